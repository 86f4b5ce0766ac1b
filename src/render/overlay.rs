//! The overlay (`shaders/overlay.wgsl`): the light directions in a corner, as in the paper's Figure 1,
//! and a status line (frame rate, lights, shadow maps drawn, and with a shadow budget how many
//! lights are shadowed: "shadowed 4 of 64").
//!
//! Input: the frame's [`Light`]s and a [`Status`]. Output: instanced quads drawn over the tonemapped
//! frame. The disk is an azimuthal equidistant projection of the whole sphere around the zenith:
//! the centre is +Y, the radius is proportional to the angle from +Y (the ring halfway out is the
//! horizon, the rim is −Y), the top of the disk is −Z (forward) and its right is +X, as seen from
//! above (the fisheye convention of DESIGN.md). A dot's area is proportional to its light's power.
//! A leaf of the render tree; the renderer draws it last, over the tonemapped frame.

use crate::lights::Light;
use std::fmt::Write;

/// One quad, as `Instance` in overlay.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
struct Instance {
    centre: [f32; 2],
    half_size: [f32; 2],
    color: [f32; 4],
    shape: u32,
}

const RECT: u32 = 0;
const DISK: u32 = 1;
const RING: u32 = 2;
/// Quads the instance buffer holds: every light's dot plus the text (each lit font pixel is a quad).
const MAX_INSTANCES: usize = 4096;

/// What the status line says.
#[derive(Clone, Copy, Debug, Default)]
pub struct Status {
    /// Frames per second, if known (left out in tests that compare frames).
    pub fps: Option<f32>,
    pub lights: usize,
    pub maps_drawn: u32,
    /// With a shadow budget (the lights carry `shadowed` marks): how many are marked, i.e. drawn
    /// with a shadow map; the rest are drawn unoccluded.
    pub shadowed: Option<usize>,
    /// The stream is down and the lights shown are the last ones received.
    pub stale: bool,
}

pub struct OverlayPass {
    pipeline: wgpu::RenderPipeline,
    globals: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    instances: wgpu::Buffer,
    staging: Vec<Instance>,
    text: String,
    count: u32,
}

impl OverlayPass {
    pub fn new(device: &wgpu::Device, format: wgpu::TextureFormat) -> OverlayPass {
        let shader = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("overlay.wgsl"),
            source: wgpu::ShaderSource::Wgsl(include_str!("../../shaders/overlay.wgsl").into()),
        });
        let bgl = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("overlay"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::VERTEX,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            }],
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("overlay"),
            bind_group_layouts: &[Some(&bgl)],
            immediate_size: 0,
        });
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("overlay"),
            layout: Some(&layout),
            vertex: wgpu::VertexState {
                module: &shader,
                entry_point: Some("vs_overlay"),
                compilation_options: Default::default(),
                buffers: &[Some(wgpu::VertexBufferLayout {
                    array_stride: std::mem::size_of::<Instance>() as u64,
                    step_mode: wgpu::VertexStepMode::Instance,
                    attributes: &wgpu::vertex_attr_array![
                        0 => Float32x2, 1 => Float32x2, 2 => Float32x4, 3 => Uint32
                    ],
                })],
            },
            primitive: wgpu::PrimitiveState {
                topology: wgpu::PrimitiveTopology::TriangleStrip,
                ..Default::default()
            },
            depth_stencil: None,
            multisample: wgpu::MultisampleState::default(),
            fragment: Some(wgpu::FragmentState {
                module: &shader,
                entry_point: Some("fs_overlay"),
                compilation_options: Default::default(),
                targets: &[Some(wgpu::ColorTargetState {
                    format,
                    blend: Some(wgpu::BlendState::ALPHA_BLENDING),
                    write_mask: wgpu::ColorWrites::ALL,
                })],
            }),
            multiview_mask: None,
            cache: None,
        });
        let globals = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("overlay globals"),
            size: 16,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("overlay"),
            layout: &bgl,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: globals.as_entire_binding(),
            }],
        });
        let instances = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("overlay instances"),
            size: (MAX_INSTANCES * std::mem::size_of::<Instance>()) as u64,
            usage: wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        OverlayPass {
            pipeline,
            globals,
            bind_group,
            instances,
            staging: Vec::with_capacity(MAX_INSTANCES),
            text: String::with_capacity(64),
            count: 0,
        }
    }

    /// Builds and uploads this frame's quads.
    pub fn prepare(
        &mut self,
        queue: &wgpu::Queue,
        size: (u32, u32),
        lights: &[Light],
        status: &Status,
    ) {
        let (w, h) = (size.0 as f32, size.1 as f32);
        queue.write_buffer(&self.globals, 0, bytemuck::cast_slice(&[w, h, 0.0, 0.0]));
        self.staging.clear();
        // The disk: 15 % of the shorter side in radius, in the top-left corner.
        let radius = (0.15 * w.min(h)).max(16.0);
        let margin = 6.0;
        let c = [margin + radius, margin + radius];
        self.push(c, radius, [0.0, 0.0, 0.0, 0.5], DISK);
        self.push(c, radius, [0.8, 0.8, 0.8, 0.6], RING);
        self.push(c, 0.5 * radius, [0.8, 0.8, 0.6, 0.6], RING); // the horizon
        let lum = |l: &Light| {
            0.2126 * l.irradiance[0] + 0.7152 * l.irradiance[1] + 0.0722 * l.irradiance[2]
        };
        let max_lum = lights.iter().map(lum).fold(0.0f32, f32::max);
        for l in lights {
            if self.staging.len() + 400 >= MAX_INSTANCES {
                break; // keep room for the text
            }
            let [x, y, z] = l.to_light;
            let theta = y.clamp(-1.0, 1.0).acos();
            let horiz = (x * x + z * z).sqrt();
            let (ux, uz) = if horiz > 1e-6 {
                (x / horiz, z / horiz)
            } else {
                (0.0, 0.0)
            };
            let r = radius * theta / std::f32::consts::PI;
            // Area ∝ power: radius ∝ √power, from 1 to 5 pixels.
            let size = 1.0 + 4.0 * (lum(l) / max_lum.max(1e-30)).max(0.0).sqrt();
            let m = l.irradiance.iter().cloned().fold(1e-30f32, f32::max);
            let col = l.irradiance.map(|v| 0.35 + 0.65 * (v / m).max(0.0));
            self.push(
                [c[0] + ux * r, c[1] + uz * r],
                size,
                [col[0], col[1], col[2], 0.95],
                DISK,
            );
        }
        // The status line under the disk.
        status_text(status, &mut self.text);
        let px = (h / 160.0).floor().max(1.0);
        let origin = [margin, c[1] + radius + margin];
        self.push_text(origin, px);
        let n = self.staging.len().min(MAX_INSTANCES);
        queue.write_buffer(&self.instances, 0, bytemuck::cast_slice(&self.staging[..n]));
        self.count = n as u32;
    }

    fn push(&mut self, centre: [f32; 2], half: f32, color: [f32; 4], shape: u32) {
        self.staging.push(Instance {
            centre,
            half_size: [half, half],
            color,
            shape,
        });
    }

    fn push_text(&mut self, origin: [f32; 2], px: f32) {
        let mut x = origin[0];
        for ch in self.text.chars() {
            let rows = glyph(ch);
            for (row, bits) in rows.iter().enumerate() {
                for col in 0..3 {
                    if bits & (0b100 >> col) != 0 && self.staging.len() < MAX_INSTANCES {
                        self.staging.push(Instance {
                            centre: [
                                x + (col as f32 + 0.5) * px,
                                origin[1] + (row as f32 + 0.5) * px,
                            ],
                            half_size: [0.5 * px, 0.5 * px],
                            color: [1.0, 1.0, 0.85, 0.95],
                            shape: RECT,
                        });
                    }
                }
            }
            x += 4.0 * px;
        }
    }

    /// Records the draw into an open pass on the display target.
    pub fn draw(&self, pass: &mut wgpu::RenderPass<'_>) {
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &self.bind_group, &[]);
        pass.set_vertex_buffer(0, self.instances.slice(..));
        pass.draw(0..4, 0..self.count);
    }
}

/// The status line: frame rate, lights, shadow maps drawn, the shadow budget, and "..." while the
/// stream is down.
fn status_text(status: &Status, out: &mut String) {
    out.clear();
    if let Some(fps) = status.fps {
        let _ = write!(out, "{fps:.1} fps ");
    }
    let _ = write!(out, "{} lights {} maps", status.lights, status.maps_drawn);
    if let Some(k) = status.shadowed {
        let _ = write!(out, " shadowed {k} of {}", status.lights);
    }
    if status.stale {
        out.push_str(" ..."); // the stream is down; these are the last lights received
    }
}

/// A 3 × 5 bitmap glyph, one row per entry, most significant of 3 bits on the left.
/// Letters the status line does not use are drawn as a small box.
fn glyph(c: char) -> [u8; 5] {
    match c {
        '0' => [0b111, 0b101, 0b101, 0b101, 0b111],
        '1' => [0b010, 0b110, 0b010, 0b010, 0b111],
        '2' => [0b111, 0b001, 0b111, 0b100, 0b111],
        '3' => [0b111, 0b001, 0b111, 0b001, 0b111],
        '4' => [0b101, 0b101, 0b111, 0b001, 0b001],
        '5' => [0b111, 0b100, 0b111, 0b001, 0b111],
        '6' => [0b111, 0b100, 0b111, 0b101, 0b111],
        '7' => [0b111, 0b001, 0b001, 0b001, 0b001],
        '8' => [0b111, 0b101, 0b111, 0b101, 0b111],
        '9' => [0b111, 0b101, 0b111, 0b001, 0b111],
        '.' => [0b000, 0b000, 0b000, 0b000, 0b010],
        'f' => [0b011, 0b100, 0b111, 0b100, 0b100],
        'p' => [0b111, 0b101, 0b111, 0b100, 0b100],
        's' => [0b011, 0b100, 0b010, 0b001, 0b110],
        'l' => [0b100, 0b100, 0b100, 0b100, 0b111],
        'i' => [0b010, 0b000, 0b010, 0b010, 0b010],
        'g' => [0b111, 0b100, 0b101, 0b101, 0b111],
        'h' => [0b100, 0b100, 0b111, 0b101, 0b101],
        't' => [0b010, 0b111, 0b010, 0b010, 0b011],
        'm' => [0b000, 0b111, 0b111, 0b101, 0b101],
        'a' => [0b000, 0b110, 0b011, 0b101, 0b111],
        'd' => [0b001, 0b001, 0b111, 0b101, 0b111],
        'o' => [0b000, 0b111, 0b101, 0b101, 0b111],
        'w' => [0b000, 0b101, 0b101, 0b111, 0b111],
        'e' => [0b000, 0b111, 0b111, 0b100, 0b111],
        ' ' => [0; 5],
        _ => [0b000, 0b111, 0b101, 0b111, 0b000],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_status_line_shows_the_shadow_budget_when_there_is_one() {
        let mut text = String::new();
        let status = Status {
            lights: 64,
            maps_drawn: 3,
            ..Status::default()
        };
        status_text(&status, &mut text);
        assert_eq!(text, "64 lights 3 maps");
        status_text(
            &Status {
                shadowed: Some(4),
                ..status
            },
            &mut text,
        );
        assert_eq!(text, "64 lights 3 maps shadowed 4 of 64");
        // Every character of it has a glyph (the fallback box is for letters never shown).
        let fallback = glyph('?');
        assert!(text.chars().all(|c| glyph(c) != fallback), "{text}");
    }
}
