// Lighting pass: every pixel of the G-buffer lit by all light groups through their shadow maps
// (src/render/shading.rs). Linear radiance × exposure goes to an Rgba32Float target.
//
// L_out = Σ_k E_k · f(l_k, v) · max(0, n·l_k) · V_k                      (DESIGN.md, "A light")
// f(l, v) = ρ/π + k_s · (s + 8)/(8π) · (n·h)^s,  h = normalize(l + v)     (src/render/scene.rs)
// No ambient term: the lights carry all of the map's energy.

const PI: f32 = 3.14159265358979;
// Mirror MAX_LIGHTS, MAX_LIST / 4 and MAX_DRAWS in src/render/shading.rs.
const c_max_lights: u32 = 1024u;
const c_max_list_vec4: u32 = 4096u;
const c_max_draws: u32 = 256u;
// PCF taps per shadow lookup: 1 (one bilinear 2 × 2 tap), 4 (a 3 × 3 tent), or 0 (no shadows).
// A pipeline constant, not a uniform: lavapipe runs both sides of every branch, so a uniform
// choice between 1 and 4 taps would cost 5.
override c_pcf_taps: u32 = 1u;
// Whether this pipeline shades glossy pixels (the stencil sends it only those); the Lambertian
// pipeline leaves the lobe's code out.
override c_glossy: bool = true;

struct Globals {
    camera_pos: vec4<f32>,
    // x: exposure; y: glossy-refinement threshold t (the lobe's fraction of its peak below which a
    // light gets diffuse only); z: normal offset of shadow lookups (world units); w: one shadow texel
    // in texture coordinates.
    params: vec4<f32>,
    // x: 1 = lights culled per draw; y: 1 = glossy refinement; z: unused; w: number of groups.
    flags: vec4<u32>,
    // The shadow maps' fit: xyz = centre of the casters' bounding sphere, w = its radius r.
    fit_sphere: vec4<f32>,
    // x: distance from the centre to the farthest point of the scene.
    fit_reach: vec4<f32>,
};

struct Light {
    // xyz: unit vector toward the light; w: its angular radius, radians (ALGORITHMS.md §12).
    to_light: vec4<f32>,
    // rgb: radiance × sr.
    irradiance: vec4<f32>,
    // A two-part extent (ALGORITHMS.md §12): x = the core's share of the light (0: none, draw the
    // one disc of to_light.w), y = the core's disc, z = the rest's, radians.
    extent: vec4<f32>,
};

struct Group {
    // x: layer in t_shadow, or 0xffffffff for no shadow map (lit); members are
    // u_lights.items[y .. y + z]; w: unused.
    info: vec4<u32>,
    // World → shadow texture: u = dot(u_row.xyz, p) + u_row.w, likewise v and depth. The rows are
    // shadow.wgsl's shadow_clip for the direction the map was drawn from, mapped to texture
    // coordinates (ShadowFit::texture_rows in src/render/shadow.rs): three loads and three dot
    // products per lookup instead of deriving the image axes at every pixel.
    u_row: vec4<f32>,
    v_row: vec4<f32>,
    depth_row: vec4<f32>,
};

// Uniform rather than storage buffers: lavapipe (Mesa 22.3) loads a storage buffer one SIMD lane at
// a time.
struct Lights { items: array<Light, c_max_lights> };
struct Groups { items: array<Group, c_max_lights> };
// Group indices, four to a vec4 (uniform arrays have a 16-byte stride).
struct Lists { items: array<vec4<u32>, c_max_list_vec4> };
// Per draw: xy = (offset, count) into u_lists of the groups that can reach the draw's normal cone.
struct Draws { items: array<vec4<u32>, c_max_draws> };

@group(0) @binding(0) var<uniform> u_globals: Globals;
@group(0) @binding(1) var<uniform> u_lights: Lights;
@group(0) @binding(2) var<uniform> u_groups: Groups;
@group(0) @binding(3) var<uniform> u_lists: Lists;
@group(0) @binding(4) var<uniform> u_draws: Draws;
@group(0) @binding(5) var t_shadow: texture_depth_2d_array;
@group(0) @binding(6) var s_shadow: sampler_comparison;
@group(0) @binding(7) var t_position: texture_2d<f32>;
@group(0) @binding(8) var t_normal: texture_2d<f32>;
@group(0) @binding(9) var t_material: texture_2d<f32>;

@vertex
fn vs_light(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    // One triangle covering the viewport: (−1,−1), (3,−1), (−1,3).
    let xy = vec2<f32>(f32((i << 1u) & 2u), f32(i & 2u)) * 2.0 - vec2<f32>(1.0);
    return vec4<f32>(xy, 0.0, 1.0);
}

// Largest penumbra half-width, in shadow texels (a bound on the taps' spread).
const c_max_penumbra_texels: f32 = 64.0;

// Fraction of group `gi`'s shadow map that sees `world` lit (PCF). A light of angular radius
// `radius` (a sun, or a light standing for a patch of sky) casts a penumbra whose half-width is
// the receiver's distance behind its blocker times tan(radius): five depth loads over the widest
// penumbra the scene allows find the nearest blocker, and four bilinear taps spread that far
// apart filter the edge (a small PCSS).
fn visibility(gi: u32, layer: u32, world: vec3<f32>, n: vec3<f32>, radius: f32) -> f32 {
    if c_pcf_taps == 0u || layer == 0xffffffffu {
        return 1.0;
    }
    // Offset along the normal so a surface does not shadow itself (shadow acne).
    let p = vec4<f32>(world + n * u_globals.params.z, 1.0);
    let g = u_groups.items[gi];
    let uv = vec2<f32>(dot(g.u_row, p), dot(g.v_row, p));
    if any(uv < vec2<f32>(0.0)) || any(uv > vec2<f32>(1.0)) {
        return 1.0; // outside the casters' footprint: nothing can block this light here
    }
    // Beyond the far plane counts as "at the far plane": behind every caster, in front of the clear.
    let depth = clamp(dot(g.depth_row, p), 0.0, 1.0);
    var h = 0.5 * u_globals.params.w;
    var soft = false;
    if radius > 0.0 {
        let size = vec2<f32>(textureDimensions(t_shadow));
        let cap = c_max_penumbra_texels * u_globals.params.w;
        let slope = tan(min(radius, 0.5));
        // The widest penumbra: a blocker as far in front as the scene reaches.
        let search = clamp(slope * u_globals.fit_reach.x * length(g.u_row.xyz), h, cap);
        var blocker = 1.0;
        for (var i = 0u; i < 5u; i++) {
            var o = vec2<f32>(0.0);
            if i > 0u {
                o = vec2<f32>(select(-search, search, (i & 1u) != 0u), select(-search, search, (i & 2u) != 0u));
            }
            let texel = clamp(vec2<i32>((uv + o) * size), vec2<i32>(0), vec2<i32>(size) - vec2<i32>(1));
            blocker = min(blocker, textureLoad(t_shadow, texel, i32(layer), 0));
        }
        if blocker < depth {
            // Depth and u are linear in the world position (orthographic maps): world distance
            // = Δdepth / |∇depth|, texture distance = world distance × |∇u|.
            let behind = (depth - blocker) / max(length(g.depth_row.xyz), 1e-12);
            let spread = behind * slope * length(g.u_row.xyz);
            h = clamp(spread, h, cap);
            soft = true;
        }
    }
    if c_pcf_taps == 1u && !soft {
        return textureSampleCompareLevel(t_shadow, s_shadow, uv, layer, depth);
    }
    // Four bilinear taps 2h apart: a 3 × 3 tent over the texels for h of half a texel, the
    // light's penumbra for a soft light.
    var sum = 0.0;
    for (var i = 0u; i < 4u; i++) {
        let o = vec2<f32>(select(-h, h, (i & 1u) != 0u), select(-h, h, (i & 2u) != 0u));
        sum += textureSampleCompareLevel(t_shadow, s_shadow, uv + o, layer, depth);
    }
    return sum / 4.0;
}

@fragment
fn fs_light(@builtin(position) frag: vec4<f32>) -> @location(0) vec4<f32> {
    let texel = vec2<i32>(frag.xy);
    let g_normal = textureLoad(t_normal, texel, 0);
    if dot(g_normal.xyz, g_normal.xyz) == 0.0 {
        return vec4<f32>(0.0, 0.0, 0.0, 1.0); // background: nothing drawn here
    }
    let g_position = textureLoad(t_position, texel, 0);
    let g_material = textureLoad(t_material, texel, 0);
    let world = g_position.xyz;
    let n = g_normal.xyz;
    let v = normalize(u_globals.camera_pos.xyz - world);
    let r = reflect(-v, n);
    let diffuse = g_material.rgb / PI;
    let ks = g_normal.w;
    let s = max(g_material.a, 1.0);
    let lobe_norm = ks * (s + 8.0) / (8.0 * PI);
    // The lobe (n·h)^s falls below t of its peak for n·h < t^(1/s), i.e. for lights farther than
    // 2·acos(t^(1/s)) from the reflected view direction: cos 2x = 2 cos² x − 1.
    let cos_cone = 2.0 * pow(u_globals.params.y, 2.0 / s) - 1.0;
    let refine = u_globals.flags.y != 0u;

    // Culling on: the list of the pixel's draw (its normal bucket). Off: every group, in order.
    let culled = u_globals.flags.x != 0u;
    let draw = min(u32(g_position.w), c_max_draws - 1u);
    let list = select(vec2<u32>(0u, u_globals.flags.w), u_draws.items[draw].xy, culled);
    var radiance = vec3<f32>(0.0);
    for (var i = 0u; i < list.y; i++) {
        var gi = i;
        if culled {
            let e = list.x + i;
            gi = u_lists.items[e >> 2u][e & 3u];
        }
        let info = u_groups.items[gi].info;
        var sum = vec3<f32>(0.0);
        // No early `continue` for lights behind the surface: max(0, n·l) keeps the loop uniform.
        for (var k = info.y; k < info.y + info.z; k++) {
            let l = u_lights.items[k].to_light.xyz;
            let ndl = max(dot(n, l), 0.0);
            var f = diffuse;
            if c_glossy && ks > 0.0 && (!refine || dot(l, r) > cos_cone) {
                let h = normalize(l + v);
                f += vec3<f32>(lobe_norm * pow(max(dot(n, h), 0.0), s));
            }
            sum += u_lights.items[k].irradiance.rgb * f * ndl;
        }
        // Only lights that reach the surface pay for a shadow lookup.
        if any(sum > vec3<f32>(0.0)) {
            // The group's penumbra is its first (brightest-keyed) member's disc; a light with a
            // map of its own and a two-part extent draws its two discs about the same direction,
            // weighed by their shares (two lookups of one map). A group keeps one disc: its
            // first member's glow would blur its brighter members' shadows.
            let first = u_lights.items[info.y];
            var seen: f32;
            if first.extent.x > 0.0 && info.z == 1u {
                let core = visibility(gi, info.x, world, n, first.extent.y);
                let rest = visibility(gi, info.x, world, n, first.extent.z);
                seen = mix(rest, core, first.extent.x);
            } else {
                seen = visibility(gi, info.x, world, n, first.to_light.w);
            }
            radiance += sum * seen;
        }
    }
    return vec4<f32>(radiance * u_globals.params.x, 1.0);
}
