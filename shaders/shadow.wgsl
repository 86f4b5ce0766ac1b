// Shadow pass (ALGORITHMS.md §6): depth only, one layer of the shadow-map array per draw.
// The pipeline has no fragment stage; the depth bias is set on the pipeline (src/render/shadow.rs).

struct Fit {
    // xyz: centre of the casters' bounding sphere; w: its radius r.
    sphere: vec4<f32>,
    // x: distance from the centre to the farthest point of the scene.
    reach: vec4<f32>,
};

// Per layer of the shadow-map array: xyz = the direction toward the light it is drawn from.
@group(0) @binding(0) var<storage, read> s_shadow_axes: array<vec4<f32>>;
@group(0) @binding(1) var<uniform> u_fit: Fit;

// World → shadow clip of the map drawn along `to_light`: orthographic, fitted to the casters'
// sphere. The same function is in light.wgsl, and ShadowFit::project in src/render/shadow.rs
// derives it; all three must agree.
fn shadow_clip(to_light: vec3<f32>, p: vec3<f32>) -> vec3<f32> {
    let up = select(vec3<f32>(0.0, 1.0, 0.0), vec3<f32>(0.0, 0.0, 1.0), abs(to_light.y) > 0.99);
    let x_axis = normalize(cross(up, to_light));
    let y_axis = cross(to_light, x_axis);
    let d = p - u_fit.sphere.xyz;
    let r = u_fit.sphere.w;
    return vec3<f32>(dot(x_axis, d) / r, dot(y_axis, d) / r, (r - dot(to_light, d)) / (r + u_fit.reach.x));
}

@vertex
fn vs_shadow(
    @location(0) position: vec3<f32>,
    // Each draw is one instance whose index is the layer being drawn: it selects the layer's light.
    @builtin(instance_index) layer: u32,
) -> @builtin(position) vec4<f32> {
    return vec4<f32>(shadow_clip(s_shadow_axes[layer].xyz, position), 1.0);
}
