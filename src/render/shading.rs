//! Shading, deferred: a geometry pass writes what each pixel sees (`shaders/gbuffer.wgsl`), then a
//! lighting pass lights every pixel by the light groups through their shadow maps, into a linear HDR
//! target (`shaders/light.wgsl`).
//!
//! Input: the grouped lights ([`Grouping`]), each group's [`GroupShadow`], the camera. Output: the
//! HDR target (linear radiance × exposure, Rgba16Float) that the tonemap pass displays and the tests
//! read back.
//!
//! Two things shape this pass on lavapipe (Mesa's software Vulkan), where the figures of issue 4 are
//! taken. Fragment shaders run on 4 × 4 pixel blocks, so a mesh of sub-pixel triangles (the
//! full-resolution bunny at 320 × 240) would run a many-light loop many times per covered pixel: the
//! geometry pass pays for those triangles with a trivial shader and the lighting pass is one
//! full-screen triangle. And a uniform array indexed by a loop counter is loaded one SIMD lane at a
//! time, which costs more than the shading: so the lights go in windows of [`WINDOW`], one draw per
//! window (a dynamic uniform offset), and the shader reads slot j of the window with j a constant.
//! The draws add up in the target.
//!
//! Culling by normal extent (ALGORITHMS.md §6), per pixel, whose normal n is exact here: a group of
//! lights whose directions lie in a cone (axis a, half-angle β) can light n only if n·a > −sin β.
//! Groups are ordered by direction so that each window's lights are close together, and a pixel
//! outside a window's cone skips the whole draw; inside, it skips the groups whose cone it is outside.

use super::cluster::{Group, Grouping};
use super::scene::{Camera, Vertex};
use super::shadow::{GroupShadow, NO_LAYER, SceneBuffers};
use crate::lights::Light;
use glam::{Vec2, Vec3};

/// G-buffer formats: position, normal + k_s, albedo + shininess.
pub const GBUFFER_FORMATS: [wgpu::TextureFormat; 3] = [
    wgpu::TextureFormat::Rgba32Float,
    wgpu::TextureFormat::Rgba32Float,
    wgpu::TextureFormat::Rgba8Unorm,
];
/// Format of the HDR target (blendable, unlike Rgba32Float without an optional feature).
pub const HDR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba16Float;
/// Format of the camera's depth buffer.
pub const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
/// Lights per lighting draw (`c_window` in light.wgsl).
pub const WINDOW: usize = 16;
/// Lights the renderer shades at most (the progressive prefix beyond is cut).
pub const MAX_LIGHTS: usize = 1024;
/// A cone that every normal passes (culling off): n·a > −2 always.
const NO_CULL: [f32; 4] = [0.0, 1.0, 0.0, -2.0];

/// `Globals` in light.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
struct GlobalsRaw {
    camera_pos: [f32; 4],
    params: [f32; 4],
    flags: [u32; 4],
}

/// `Light` in light.wgsl: one slot of a window.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct LightRaw {
    /// xyz toward the light; w: 0 light, 1 light and end of its group here, 2 empty.
    pub dir: [f32; 4],
    /// rgb radiance × sr; w: shadow layer or −1.
    pub irradiance: [f32; 4],
    /// The group's shadow matrix, rows 0..3.
    pub shadow: [[f32; 4]; 3],
    /// The group's cone: axis, −sin β.
    pub cone: [f32; 4],
}

const EMPTY_SLOT: LightRaw = LightRaw {
    dir: [0.0, 1.0, 0.0, 2.0],
    irradiance: [0.0, 0.0, 0.0, -1.0],
    shadow: [[0.0; 4]; 3],
    cone: NO_CULL,
};

/// `Window` in light.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct WindowRaw {
    pub cone: [f32; 4],
    pub lights: [LightRaw; WINDOW],
}

/// The switches of the shading pass (see [`super::Options`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShadingParams {
    pub exposure: f32,
    pub cull: bool,
    /// Glossy refinement: lights whose lobe value at the pixel is below `glossy_threshold` of its
    /// peak get diffuse only; `None` evaluates the full BRDF for every light.
    pub glossy_threshold: Option<f32>,
    pub pcf_taps: u32,
    /// Normal offset of shadow lookups, world units.
    pub normal_offset: f32,
    /// Side of a shadow map, texels.
    pub shadow_size: u32,
}

/// Octahedral map of a unit vector to [0,1]², +Y at the centre.
pub fn octahedral_encode(n: Vec3) -> Vec2 {
    let mut p = Vec2::new(n.x, n.z) / (n.x.abs() + n.y.abs() + n.z.abs());
    if n.y < 0.0 {
        let s = Vec2::new(
            if p.x >= 0.0 { 1.0 } else { -1.0 },
            if p.y >= 0.0 { 1.0 } else { -1.0 },
        );
        p = (Vec2::ONE - Vec2::new(p.y.abs(), p.x.abs())) * s;
    }
    p * 0.5 + Vec2::splat(0.5)
}

/// Bin of a unit direction in a B × B grid of the octahedral map (`side` = B).
pub fn bin_of(n: Vec3, side: u32) -> u32 {
    let uv = octahedral_encode(n) * side as f32;
    let i = (uv.x as u32).min(side - 1);
    let j = (uv.y as u32).min(side - 1);
    j * side + i
}

/// The cone (axis, −sin β) around a set of unit directions, as the shader tests it:
/// n·axis > −sin β. `NO_CULL` when β ≥ 90°, where −sin β stops being a valid bound.
fn cone_of(dirs: impl Iterator<Item = Vec3> + Clone) -> [f32; 4] {
    let axis = dirs.clone().sum::<Vec3>().normalize_or(Vec3::Y);
    let beta = dirs
        .map(|d| axis.dot(d).clamp(-1.0, 1.0).acos())
        .fold(0.0f32, f32::max)
        + 1e-3; // rounding margin
    if beta >= std::f32::consts::FRAC_PI_2 {
        NO_CULL
    } else {
        [axis.x, axis.y, axis.z, -beta.sin()]
    }
}

/// Packs the lights into windows of [`WINDOW`] slots: groups ordered by direction (a 4 × 4
/// octahedral grid of their axes, then their key), each group's members contiguous, each slot
/// carrying its group's shadow map and cone, the last slot of a group in each window flagged.
pub fn build_windows(
    lights: &[Light],
    grouping: &Grouping,
    shadows: &[GroupShadow],
    cull: bool,
    order: &mut Vec<usize>,
    out: &mut Vec<WindowRaw>,
) {
    out.clear();
    order.clear();
    order.extend(0..grouping.groups.len());
    order.sort_by_key(|&g| (bin_of(grouping.groups[g].axis, 4), grouping.groups[g].key));
    let mut slot = WINDOW; // "the current window is full"
    for &gi in order.iter() {
        let g: &Group = &grouping.groups[gi];
        let s = shadows[gi];
        let members = &grouping.order[g.first as usize..(g.first + g.count) as usize];
        let dir = |i: &u32| Vec3::from_array(lights[*i as usize].to_light).normalize_or(Vec3::Y);
        let cone = if cull { cone_of(members.iter().map(dir)) } else { NO_CULL };
        let rows = [0, 1, 2].map(|r| s.view_proj.row(r).to_array());
        let layer = if s.layer == NO_LAYER { -1.0 } else { s.layer as f32 };
        for (m, &i) in members.iter().enumerate() {
            if slot == WINDOW {
                out.push(WindowRaw {
                    cone: NO_CULL,
                    lights: [EMPTY_SLOT; WINDOW],
                });
                slot = 0;
            }
            let l = &lights[i as usize];
            let d = dir(&i);
            let last = m + 1 == members.len() || slot + 1 == WINDOW;
            out.last_mut().expect("a window").lights[slot] = LightRaw {
                dir: [d.x, d.y, d.z, if last { 1.0 } else { 0.0 }],
                irradiance: [l.irradiance[0], l.irradiance[1], l.irradiance[2], layer],
                shadow: rows,
                cone,
            };
            slot += 1;
        }
    }
    for w in out.iter_mut() {
        w.cone = if cull {
            cone_of(
                w.lights
                    .iter()
                    .filter(|l| l.dir[3] < 1.5)
                    .map(|l| Vec3::new(l.dir[0], l.dir[1], l.dir[2])),
            )
        } else {
            NO_CULL
        };
    }
}

/// A uniform buffer.
fn uniform_buffer(device: &wgpu::Device, label: &str, size: usize) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: size as u64,
        usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

/// Size-dependent targets: the G-buffer, the camera's depth and the HDR result.
struct Targets {
    size: (u32, u32),
    gbuffer: [wgpu::TextureView; 3],
    depth: wgpu::TextureView,
    hdr: wgpu::Texture,
    hdr_view: wgpu::TextureView,
}

impl Targets {
    fn new(device: &wgpu::Device, (width, height): (u32, u32)) -> Targets {
        let make = |label, format, usage| {
            device.create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size: wgpu::Extent3d {
                    width,
                    height,
                    depth_or_array_layers: 1,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage,
                view_formats: &[],
            })
        };
        let g_usage = wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING;
        let gbuffer = ["g position", "g normal", "g material"]
            .into_iter()
            .zip(GBUFFER_FORMATS)
            .map(|(label, format)| make(label, format, g_usage).create_view(&Default::default()))
            .collect::<Vec<_>>()
            .try_into()
            .expect("three targets");
        let depth = make("camera depth", DEPTH_FORMAT, wgpu::TextureUsages::RENDER_ATTACHMENT)
            .create_view(&Default::default());
        let hdr = make(
            "hdr",
            HDR_FORMAT,
            wgpu::TextureUsages::RENDER_ATTACHMENT
                | wgpu::TextureUsages::TEXTURE_BINDING
                | wgpu::TextureUsages::COPY_SRC,
        );
        let hdr_view = hdr.create_view(&Default::default());
        Targets {
            size: (width, height),
            gbuffer,
            depth,
            hdr,
            hdr_view,
        }
    }
}

/// The geometry and lighting passes, their buffers and targets.
pub struct ShadingPass {
    device: wgpu::Device,
    geometry_pipeline: wgpu::RenderPipeline,
    camera: wgpu::Buffer,
    camera_bind_group: wgpu::BindGroup,
    light_pipeline: wgpu::RenderPipeline,
    light_layout: wgpu::BindGroupLayout,
    globals: wgpu::Buffer,
    /// The windows of lights, one per `window_stride` bytes, bound one at a time (dynamic offset).
    windows: wgpu::Buffer,
    window_layout: wgpu::BindGroupLayout,
    window_bind_group: wgpu::BindGroup,
    window_stride: u64,
    n_windows: u32,
    sampler: wgpu::Sampler,
    /// Rebuilt when the targets or the shadow array change.
    light_bind_group: Option<wgpu::BindGroup>,
    /// Shadow-array generation the bind group was made for.
    bound_generation: u64,
    targets: Targets,
    // CPU staging, reused between uploads.
    window_raw: Vec<WindowRaw>,
    window_bytes: Vec<u8>,
    group_order: Vec<usize>,
}

impl ShadingPass {
    pub fn new(device: &wgpu::Device, size: (u32, u32)) -> ShadingPass {
        // The geometry pass.
        let shader = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("gbuffer.wgsl"),
            source: wgpu::ShaderSource::Wgsl(include_str!("../../shaders/gbuffer.wgsl").into()),
        });
        let camera_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("gbuffer"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::VERTEX,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: false,
                    min_binding_size: wgpu::BufferSize::new(64),
                },
                count: None,
            }],
        });
        let camera = uniform_buffer(device, "camera", 64);
        let camera_bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("gbuffer"),
            layout: &camera_layout,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: camera.as_entire_binding(),
            }],
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("gbuffer"),
            bind_group_layouts: &[Some(&camera_layout)],
            immediate_size: 0,
        });
        let geometry_pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("gbuffer"),
            layout: Some(&layout),
            vertex: wgpu::VertexState {
                module: &shader,
                entry_point: Some("vs_main"),
                compilation_options: Default::default(),
                buffers: &[Some(wgpu::VertexBufferLayout {
                    array_stride: std::mem::size_of::<Vertex>() as u64,
                    step_mode: wgpu::VertexStepMode::Vertex,
                    attributes: &wgpu::vertex_attr_array![
                        0 => Float32x3, 1 => Float32x3, 2 => Float32x3, 3 => Float32x2
                    ],
                })],
            },
            primitive: wgpu::PrimitiveState::default(),
            depth_stencil: Some(wgpu::DepthStencilState {
                format: DEPTH_FORMAT,
                depth_write_enabled: Some(true),
                depth_compare: Some(wgpu::CompareFunction::Less),
                stencil: wgpu::StencilState::default(),
                bias: wgpu::DepthBiasState::default(),
            }),
            multisample: wgpu::MultisampleState::default(),
            fragment: Some(wgpu::FragmentState {
                module: &shader,
                entry_point: Some("fs_main"),
                compilation_options: Default::default(),
                targets: &GBUFFER_FORMATS.map(|f| Some(f.into())),
            }),
            multiview_mask: None,
            cache: None,
        });

        // The lighting pass.
        let shader = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("light.wgsl"),
            source: wgpu::ShaderSource::Wgsl(include_str!("../../shaders/light.wgsl").into()),
        });
        let texture = |binding| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::FRAGMENT,
            ty: wgpu::BindingType::Texture {
                // Read with textureLoad (Rgba32Float is not filterable).
                sample_type: wgpu::TextureSampleType::Float { filterable: false },
                view_dimension: wgpu::TextureViewDimension::D2,
                multisampled: false,
            },
            count: None,
        };
        let light_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("light"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Depth,
                        view_dimension: wgpu::TextureViewDimension::D2Array,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 2,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Comparison),
                    count: None,
                },
                texture(3),
                texture(4),
                texture(5),
            ],
        });
        let window_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("light window"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::FRAGMENT,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: true,
                    min_binding_size: wgpu::BufferSize::new(std::mem::size_of::<WindowRaw>() as u64),
                },
                count: None,
            }],
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("light"),
            bind_group_layouts: &[Some(&light_layout), Some(&window_layout)],
            immediate_size: 0,
        });
        let light_pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("light"),
            layout: Some(&layout),
            vertex: wgpu::VertexState {
                module: &shader,
                entry_point: Some("vs_light"),
                compilation_options: Default::default(),
                buffers: &[],
            },
            primitive: wgpu::PrimitiveState::default(),
            depth_stencil: None,
            multisample: wgpu::MultisampleState::default(),
            fragment: Some(wgpu::FragmentState {
                module: &shader,
                entry_point: Some("fs_light"),
                compilation_options: Default::default(),
                // The windows add up.
                targets: &[Some(wgpu::ColorTargetState {
                    format: HDR_FORMAT,
                    blend: Some(wgpu::BlendState {
                        color: wgpu::BlendComponent {
                            src_factor: wgpu::BlendFactor::One,
                            dst_factor: wgpu::BlendFactor::One,
                            operation: wgpu::BlendOperation::Add,
                        },
                        alpha: wgpu::BlendComponent::REPLACE,
                    }),
                    write_mask: wgpu::ColorWrites::ALL,
                })],
            }),
            multiview_mask: None,
            cache: None,
        });
        let align = device.limits().min_uniform_buffer_offset_alignment as u64;
        let window_stride = (std::mem::size_of::<WindowRaw>() as u64).div_ceil(align) * align;
        let (windows, window_bind_group) =
            Self::window_buffer(device, &window_layout, MAX_LIGHTS.div_ceil(WINDOW) as u64 * window_stride);
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("shadow compare"),
            address_mode_u: wgpu::AddressMode::ClampToEdge,
            address_mode_v: wgpu::AddressMode::ClampToEdge,
            address_mode_w: wgpu::AddressMode::ClampToEdge,
            // Linear filtering of a comparison sampler = a 2 × 2 bilinear PCF tap.
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            // Lit where the receiver is no farther than the stored depth.
            compare: Some(wgpu::CompareFunction::LessEqual),
            ..Default::default()
        });
        ShadingPass {
            device: device.clone(),
            geometry_pipeline,
            camera,
            camera_bind_group,
            light_pipeline,
            light_layout,
            globals: uniform_buffer(device, "light globals", std::mem::size_of::<GlobalsRaw>()),
            windows,
            window_layout,
            window_bind_group,
            window_stride,
            n_windows: 0,
            sampler,
            light_bind_group: None,
            bound_generation: u64::MAX,
            targets: Targets::new(device, size),
            window_raw: Vec::new(),
            window_bytes: Vec::new(),
            group_order: Vec::new(),
        }
    }

    fn window_buffer(
        device: &wgpu::Device,
        layout: &wgpu::BindGroupLayout,
        size: u64,
    ) -> (wgpu::Buffer, wgpu::BindGroup) {
        let buffer = uniform_buffer(device, "light windows", size as usize);
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("light window"),
            layout,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                    buffer: &buffer,
                    offset: 0,
                    size: wgpu::BufferSize::new(std::mem::size_of::<WindowRaw>() as u64),
                }),
            }],
        });
        (buffer, bind_group)
    }

    pub fn size(&self) -> (u32, u32) {
        self.targets.size
    }

    /// The HDR result (linear radiance × exposure).
    pub fn hdr(&self) -> (&wgpu::Texture, &wgpu::TextureView) {
        (&self.targets.hdr, &self.targets.hdr_view)
    }

    /// Rebuilds the size-dependent targets.
    pub fn resize(&mut self, size: (u32, u32)) {
        if size != self.targets.size {
            self.targets = Targets::new(&self.device, size);
            self.light_bind_group = None;
        }
    }

    /// Packs and uploads the windows of lights; call when the lights or their shadow maps change.
    pub fn upload_lights(
        &mut self,
        queue: &wgpu::Queue,
        lights: &[Light],
        grouping: &Grouping,
        shadows: &[GroupShadow],
        cull: bool,
    ) {
        build_windows(lights, grouping, shadows, cull, &mut self.group_order, &mut self.window_raw);
        self.n_windows = self.window_raw.len() as u32;
        let stride = self.window_stride as usize;
        let size = self.window_raw.len() * stride;
        if size as u64 > self.windows.size() {
            // More than MAX_LIGHTS' worth of windows (groups straddling windows add a few).
            (self.windows, self.window_bind_group) =
                Self::window_buffer(&self.device, &self.window_layout, size.next_power_of_two() as u64);
        }
        self.window_bytes.clear();
        self.window_bytes.resize(size, 0);
        for (i, w) in self.window_raw.iter().enumerate() {
            self.window_bytes[i * stride..i * stride + std::mem::size_of::<WindowRaw>()]
                .copy_from_slice(bytemuck::bytes_of(w));
        }
        if size > 0 {
            queue.write_buffer(&self.windows, 0, &self.window_bytes);
        }
    }

    /// Windows (lighting draws) of the current set.
    pub fn windows(&self) -> u32 {
        self.n_windows
    }

    /// Writes the per-frame uniforms.
    pub fn upload_globals(&self, queue: &wgpu::Queue, camera: &Camera, p: &ShadingParams, texel_world: f32) {
        let (w, h) = self.targets.size;
        let view_proj = camera.view_proj(w as f32 / h as f32);
        queue.write_buffer(&self.camera, 0, bytemuck::cast_slice(&view_proj.to_cols_array()));
        let raw = GlobalsRaw {
            camera_pos: camera.eye.extend(1.0).to_array(),
            params: [
                p.exposure,
                p.glossy_threshold.unwrap_or(0.0),
                p.normal_offset * texel_world,
                1.0 / p.shadow_size as f32,
            ],
            flags: [0, p.glossy_threshold.is_some() as u32, p.pcf_taps, 0],
        };
        queue.write_buffer(&self.globals, 0, bytemuck::bytes_of(&raw));
    }

    /// Records the geometry and the lighting pass.
    pub fn draw(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        scene: &SceneBuffers,
        shadow_view: &wgpu::TextureView,
        shadow_generation: u64,
    ) {
        let t = &self.targets;
        {
            let clear = wgpu::Operations {
                load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                store: wgpu::StoreOp::Store,
            };
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("geometry pass"),
                color_attachments: &t.gbuffer.each_ref().map(|view| {
                    Some(wgpu::RenderPassColorAttachment {
                        view,
                        depth_slice: None,
                        resolve_target: None,
                        ops: clear,
                    })
                }),
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &t.depth,
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(1.0),
                        store: wgpu::StoreOp::Discard,
                    }),
                    stencil_ops: None,
                }),
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&self.geometry_pipeline);
            pass.set_bind_group(0, &self.camera_bind_group, &[]);
            pass.set_vertex_buffer(0, scene.vertices.slice(..));
            pass.set_index_buffer(scene.indices.slice(..), wgpu::IndexFormat::Uint32);
            pass.draw_indexed(scene.all.clone(), 0, 0..1);
        }
        if self.bound_generation != shadow_generation {
            self.light_bind_group = None;
        }
        let bind_group = self.light_bind_group.get_or_insert_with(|| {
            fn buffer(binding: u32, b: &wgpu::Buffer) -> wgpu::BindGroupEntry<'_> {
                wgpu::BindGroupEntry {
                    binding,
                    resource: b.as_entire_binding(),
                }
            }
            fn view(binding: u32, v: &wgpu::TextureView) -> wgpu::BindGroupEntry<'_> {
                wgpu::BindGroupEntry {
                    binding,
                    resource: wgpu::BindingResource::TextureView(v),
                }
            }
            self.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("light"),
                layout: &self.light_layout,
                entries: &[
                    buffer(0, &self.globals),
                    view(1, shadow_view),
                    wgpu::BindGroupEntry {
                        binding: 2,
                        resource: wgpu::BindingResource::Sampler(&self.sampler),
                    },
                    view(3, &self.targets.gbuffer[0]),
                    view(4, &self.targets.gbuffer[1]),
                    view(5, &self.targets.gbuffer[2]),
                ],
            })
        });
        self.bound_generation = shadow_generation;
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("lighting pass"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: &self.targets.hdr_view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                    store: wgpu::StoreOp::Store,
                },
            })],
            depth_stencil_attachment: None,
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        pass.set_pipeline(&self.light_pipeline);
        pass.set_bind_group(0, &*bind_group, &[]);
        for w in 0..self.n_windows {
            let offset = (w as u64 * self.window_stride) as u32;
            pass.set_bind_group(1, &self.window_bind_group, &[offset]);
            pass.draw(0..3, 0..1);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::cluster::Clusterer;
    use glam::Mat4;

    fn light(id: u32, d: Vec3, e: f32) -> Light {
        Light {
            id,
            to_light: d.normalize().to_array(),
            irradiance: [e; 3],
            solid_angle: 0.1,
        }
    }

    fn windows(lights: &[Light], delta_deg: f32, cull: bool) -> Vec<WindowRaw> {
        let mut g = Grouping::default();
        Clusterer::new(delta_deg).group(lights, &mut g);
        let shadows: Vec<GroupShadow> = (0..g.groups.len())
            .map(|i| GroupShadow {
                layer: i as u32,
                view_proj: Mat4::IDENTITY,
            })
            .collect();
        let mut out = Vec::new();
        build_windows(lights, &g, &shadows, cull, &mut Vec::new(), &mut out);
        out
    }

    #[test]
    fn every_light_lands_in_one_slot_and_groups_end_flagged() {
        // 20 lights around the sky plus a tight cluster of 5 around a sun.
        let mut lights: Vec<Light> = (0..20)
            .map(|k| {
                let phi = k as f32 * 2.399_963;
                let y = 1.0 - 2.0 * (k as f32 + 0.5) / 20.0;
                let r = (1.0 - y * y).sqrt();
                light(k, Vec3::new(r * phi.cos(), y, r * phi.sin()), 1.0)
            })
            .collect();
        for k in 0..5 {
            lights.push(light(20 + k, Vec3::new(0.01 * k as f32, 0.2, -1.0), 50.0));
        }
        let w = windows(&lights, 3.0, true);
        let used: Vec<&LightRaw> = w.iter().flat_map(|w| w.lights.iter()).filter(|l| l.dir[3] < 1.5).collect();
        assert_eq!(used.len(), lights.len());
        let total: f32 = used.iter().map(|l| l.irradiance[0]).sum();
        assert_eq!(total, 20.0 + 250.0, "energy is neither lost nor doubled");
        // The sun's five lights share one layer, and a flush ends each run of a layer.
        let sun_layer = used.iter().find(|l| l.irradiance[0] == 50.0).unwrap().irradiance[3];
        assert_eq!(used.iter().filter(|l| l.irradiance[3] == sun_layer).count(), 5);
        for w in &w {
            let slots: Vec<&LightRaw> = w.lights.iter().filter(|l| l.dir[3] < 1.5).collect();
            for pair in slots.windows(2) {
                if pair[0].irradiance[3] != pair[1].irradiance[3] {
                    assert_eq!(pair[0].dir[3], 1.0, "a group's last slot flushes");
                }
            }
            assert_eq!(slots.last().unwrap().dir[3], 1.0, "a window's last slot flushes");
        }
    }

    #[test]
    fn cones_hold_their_lights_and_culling_off_passes_everything() {
        let lights: Vec<Light> = (0..40)
            .map(|k| {
                let phi = k as f32 * 2.399_963;
                let y = 1.0 - 2.0 * (k as f32 + 0.5) / 40.0;
                let r = (1.0 - y * y).sqrt();
                light(k, Vec3::new(r * phi.cos(), y, r * phi.sin()), 1.0)
            })
            .collect();
        for w in windows(&lights, 0.0, true) {
            let axis = Vec3::new(w.cone[0], w.cone[1], w.cone[2]);
            for l in w.lights.iter().filter(|l| l.dir[3] < 1.5) {
                let d = Vec3::new(l.dir[0], l.dir[1], l.dir[2]);
                // A normal equal to a light's direction must pass its window's test.
                assert!(d.dot(axis) > w.cone[3], "{d} outside {:?}", w.cone);
            }
        }
        for w in windows(&lights, 0.0, false) {
            assert_eq!(w.cone, NO_CULL);
            assert!(w.lights.iter().all(|l| l.cone == NO_CULL));
        }
    }

    #[test]
    fn a_normal_facing_away_from_a_tight_cone_is_culled() {
        let c = cone_of([Vec3::Y, Vec3::new(0.05, 1.0, 0.0).normalize()].into_iter());
        let axis = Vec3::new(c[0], c[1], c[2]);
        assert!(Vec3::Y.dot(axis) > c[3]);
        assert!(Vec3::X.dot(axis) > c[3], "a normal at 90° still sees lights up to β above it");
        assert!((-Vec3::Y).dot(axis) <= c[3]);
        assert!(Vec3::new(1.0, -0.2, 0.0).normalize().dot(axis) <= c[3]);
    }
}
