// Shadow pass (ALGORITHMS.md §6): depth only, one layer of the shadow-map array per draw.
// The pipeline has no fragment stage; the depth bias is set on the pipeline (src/render/shadow.rs).

// One orthographic world → clip matrix per layer of the shadow-map array.
@group(0) @binding(0) var<storage, read> s_shadow_views: array<mat4x4<f32>>;

@vertex
fn vs_shadow(
    @location(0) position: vec3<f32>,
    // Each draw is one instance whose index is the layer being drawn: it selects the layer's matrix.
    @builtin(instance_index) layer: u32,
) -> @builtin(position) vec4<f32> {
    return s_shadow_views[layer] * vec4<f32>(position, 1.0);
}
