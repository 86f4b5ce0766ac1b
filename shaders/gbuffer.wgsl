// Geometry pass: what each pixel sees (position, normal, material, draw), for the lighting pass
// (src/render/shading.rs). Deferred, because lavapipe shades in 4 × 4 blocks: a mesh of sub-pixel
// triangles would run the many-light loop up to 16 times per covered pixel; here it runs this
// cheap shader instead, and the lighting pass runs once per pixel.

struct Camera {
    view_proj: mat4x4<f32>,
};

@group(0) @binding(0) var<uniform> u_camera: Camera;

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
    // Which draw (normal bucket) the triangle belongs to: it selects the pixel's list of lights.
    @location(4) @interpolate(flat) draw: u32,
};

struct GBuffer {
    // xyz: world position; w: draw index.
    @location(0) position: vec4<f32>,
    // xyz: unit normal; w: k_s.
    @location(1) normal: vec4<f32>,
    // rgb: albedo ρ; a: shininess s.
    @location(2) material: vec4<f32>,
};

@vertex
fn vs_main(in: VertexInput, @builtin(instance_index) draw: u32) -> VertexOutput {
    var out: VertexOutput;
    out.clip = u_camera.view_proj * vec4<f32>(in.position, 1.0);
    out.world = in.position;
    out.normal = in.normal;
    out.albedo = in.albedo;
    out.gloss = in.gloss;
    // Each draw is one instance whose index is the draw's number.
    out.draw = draw;
    return out;
}

@fragment
fn fs_main(in: VertexOutput) -> GBuffer {
    var g: GBuffer;
    g.position = vec4<f32>(in.world, f32(in.draw));
    g.normal = vec4<f32>(normalize(in.normal), in.gloss.x);
    g.material = vec4<f32>(in.albedo, in.gloss.y);
    return g;
}
