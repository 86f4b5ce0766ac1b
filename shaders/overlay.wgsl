// Overlay pass: instanced quads in pixel coordinates (light dots, rings, digits of the frame rate),
// alpha-blended over the tonemapped image (src/render/overlay.rs).

struct OverlayGlobals {
    // Target size in pixels.
    viewport: vec2<f32>,
    pad: vec2<f32>,
};

@group(0) @binding(0) var<uniform> u_overlay: OverlayGlobals;

struct Instance {
    // Centre and half size, pixels (origin top left, y down).
    @location(0) centre: vec2<f32>,
    @location(1) half_size: vec2<f32>,
    @location(2) color: vec4<f32>,
    // 0: filled rectangle, 1: disk, 2: one-pixel ring.
    @location(3) shape: u32,
};

struct VertexOutput {
    @builtin(position) clip: vec4<f32>,
    // Position in the quad, −1..1 on each axis.
    @location(0) local: vec2<f32>,
    @location(1) color: vec4<f32>,
    @location(2) @interpolate(flat) shape: u32,
    @location(3) @interpolate(flat) radius_px: f32,
};

@vertex
fn vs_overlay(@builtin(vertex_index) i: u32, inst: Instance) -> VertexOutput {
    // Triangle strip over the quad's four corners.
    let corner = vec2<f32>(f32(i & 1u), f32((i >> 1u) & 1u)) * 2.0 - vec2<f32>(1.0);
    let px = inst.centre + corner * inst.half_size;
    // Pixels (y down) → NDC (y up).
    let ndc = vec2<f32>(px.x / u_overlay.viewport.x * 2.0 - 1.0, 1.0 - px.y / u_overlay.viewport.y * 2.0);
    var out: VertexOutput;
    out.clip = vec4<f32>(ndc, 0.0, 1.0);
    out.local = corner;
    out.color = inst.color;
    out.shape = inst.shape;
    out.radius_px = inst.half_size.x;
    return out;
}

@fragment
fn fs_overlay(in: VertexOutput) -> @location(0) vec4<f32> {
    let d = length(in.local) * in.radius_px; // distance from the centre, pixels
    var a = in.color.a;
    if in.shape == 1u {
        a *= clamp(in.radius_px - d + 0.5, 0.0, 1.0); // antialiased edge, one pixel wide
    } else if in.shape == 2u {
        a *= clamp(1.0 - abs(in.radius_px - 0.5 - d), 0.0, 1.0);
    }
    if a <= 0.0 {
        discard;
    }
    return vec4<f32>(in.color.rgb, a);
}
