//! Shading, deferred: a geometry pass writes what each pixel sees (`shaders/gbuffer.wgsl`), then a
//! lighting pass lights every pixel once by all light groups through their shadow maps, into a
//! linear HDR target (`shaders/light.wgsl`); and the normal cones that cull lights per draw.
//!
//! Input: the scene's device buffers ([`SceneBuffers`]), the grouped lights ([`Grouping`]), each
//! group's [`GroupShadow`] and the shadow array, the camera. Output: the HDR target (linear radiance ×
//! exposure, Rgba32Float) that the tonemap pass displays and the tests read back. Uses `scene`,
//! `cluster` and `shadow`; the renderer drives it.
//!
//! Why deferred: lavapipe runs fragment shaders on 4 × 4 pixel blocks, so a mesh of sub-pixel
//! triangles (the full-resolution bunny at 320 × 240) would run the many-light loop many times per
//! covered pixel. The geometry pass pays that with a trivial shader; the lighting pass is a
//! full-screen triangle per material class.
//!
//! Culling by normal extent (ALGORITHMS.md §6): the scene's triangles are bucketed by normal into
//! B × B bins of the octahedral map and drawn one bucket per call ([`Scene::bucketed`]). A bucket's
//! vertex normals lie in a cone (axis a, half-angle α), and a light can reach one of its pixels only
//! if to_light·a > −sin α. Each draw gets the list of groups with such a member; the geometry pass
//! stores the draw's number per pixel, and the lighting pass loops over that draw's list only.
//!
//! [`Scene::bucketed`]: super::scene::Scene::bucketed

use super::cluster::{Group, Grouping};
use super::scene::{Camera, DrawRange, SceneBuffers, Vertex};
use super::shadow::{GroupShadow, ShadowFit};
use crate::lights::Light;
use glam::Vec3;

/// G-buffer formats: position + draw, normal + k_s, albedo + shininess.
pub const GBUFFER_FORMATS: [wgpu::TextureFormat; 3] = [
    wgpu::TextureFormat::Rgba32Float,
    wgpu::TextureFormat::Rgba32Float,
    // 16-bit floats: an 8-bit albedo is off by up to 0.4 %, which the radiance tests see.
    wgpu::TextureFormat::Rgba16Float,
];
/// Draws the lighting pass knows lists for (`c_max_draws` in light.wgsl).
pub const MAX_DRAWS: usize = 256;
/// Format of the HDR target.
pub const HDR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Float;
/// Format of the camera's depth buffer.
/// Format of the camera's depth buffer; its stencil marks glossy pixels (see [`ShadingPass`]).
pub const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth24PlusStencil8;
/// Stencil values of the material classes: pixels with no surface keep 0 and are never lit (the
/// stencil test drops them before the lighting shader runs).
const STENCIL_LAMBERTIAN: u32 = 1;
const STENCIL_GLOSSY: u32 = 2;

/// `Globals` in light.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
struct GlobalsRaw {
    camera_pos: [f32; 4],
    params: [f32; 4],
    flags: [u32; 4],
    fit: [[f32; 4]; 2],
}

/// `Light` in light.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct LightRaw {
    to_light: [f32; 4],
    irradiance: [f32; 4],
    extent: [f32; 4],
}

impl LightRaw {
    pub fn from_light(l: &Light) -> LightRaw {
        let [x, y, z] = l.to_light;
        let [r, g, b] = l.irradiance;
        LightRaw {
            // w: the light's angular radius (ALGORITHMS.md §12), for its penumbra.
            to_light: [x, y, z, l.angular_radius.max(0.0)],
            irradiance: [r, g, b, 0.0],
            // A two-part extent (ALGORITHMS.md §12): core share, core radius, rest radius; a
            // share of 0 draws the one disc of `to_light.w`.
            extent: l.extent.map_or([0.0; 4], |e| {
                [
                    e.core_share.clamp(0.0, 1.0),
                    e.core_radius.max(0.0),
                    e.rest_radius.max(0.0),
                    0.0,
                ]
            }),
        }
    }
}

/// `Group` in light.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
struct GroupRaw {
    /// layer, first, count, unused.
    info: [u32; 4],
    /// World → (u, v, depth) of the group's shadow map ([`ShadowFit::texture_rows`] of the
    /// direction it was drawn from).
    rows: [[f32; 4]; 3],
}

/// Lights (and groups) the shading pass holds: the uniform arrays in light.wgsl are this long.
pub const MAX_LIGHTS: usize = 1024;
/// Entries of the draws' group lists (`c_max_list_vec4` × 4 in light.wgsl). A set whose lists
/// would not fit is shaded without culling.
pub const MAX_LIST: usize = 16384;

/// The switches of the shading pass (the renderer sets them from its `Options`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShadingParams {
    pub exposure: f32,
    pub cull: bool,
    /// Glossy refinement: lights whose lobe value at the pixel is below `glossy_threshold` of its
    /// peak get diffuse only; `None` evaluates the full BRDF for every light.
    pub glossy_threshold: Option<f32>,
    /// Normal offset of shadow lookups, world units.
    pub normal_offset: f32,
    /// Side of a shadow map, texels.
    pub shadow_size: u32,
}

/// Per draw, (offset, count) into `list` of the groups that can reach the draw's normal cone; then
/// one more entry listing every group (culling off).
pub fn draw_lists(
    draws: &[DrawRange],
    lights: &[Light],
    grouping: &Grouping,
    lists: &mut Vec<[u32; 2]>,
    list: &mut Vec<u32>,
) {
    lists.clear();
    list.clear();
    for d in draws {
        let offset = list.len() as u32;
        for (gi, g) in grouping.groups.iter().enumerate() {
            let members = &grouping.order[g.first as usize..(g.first + g.count) as usize];
            let reaches = members
                .iter()
                .any(|&i| Vec3::from_array(lights[i as usize].to_light).dot(d.axis) > -d.sin_alpha);
            if reaches {
                list.push(gi as u32);
            }
        }
        lists.push([offset, list.len() as u32 - offset]);
    }
    let offset = list.len() as u32;
    list.extend(0..grouping.groups.len() as u32);
    lists.push([offset, grouping.groups.len() as u32]);
}

/// A uniform buffer of fixed size.
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
        let depth = make(
            "camera depth",
            DEPTH_FORMAT,
            wgpu::TextureUsages::RENDER_ATTACHMENT,
        )
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
    /// [Lambertian pixels, glossy pixels].
    light_pipelines: [wgpu::RenderPipeline; 2],
    light_layout: wgpu::BindGroupLayout,
    globals: wgpu::Buffer,
    lights: wgpu::Buffer,
    groups: wgpu::Buffer,
    list: wgpu::Buffer,
    draws: wgpu::Buffer,
    /// Whether this set's lists fit [`MAX_LIST`] (otherwise culling is off for it).
    lists_fit: bool,
    n_groups: u32,
    sampler: wgpu::Sampler,
    /// Rebuilt when the targets or the shadow array change.
    light_bind_group: Option<wgpu::BindGroup>,
    /// Shadow-array generation the bind group was made for.
    bound_generation: u64,
    targets: Targets,
    // CPU staging, reused between uploads.
    light_raw: Vec<LightRaw>,
    group_raw: Vec<GroupRaw>,
    lists_raw: Vec<[u32; 2]>,
    list_raw: Vec<u32>,
    draw_raw: Vec<[u32; 4]>,
}

impl ShadingPass {
    /// `pcf_taps`: 0, 1 or 4, compiled into the lighting pipeline.
    pub fn new(
        device: &wgpu::Device,
        size: (u32, u32),
        draws: usize,
        pcf_taps: u32,
    ) -> ShadingPass {
        assert!(
            draws <= MAX_DRAWS,
            "{draws} draws; the lighting pass knows {MAX_DRAWS}"
        );
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
            // Meshes are closed and wound counter-clockwise outward (OBJ's convention, and the boxes'),
            // the ground faces up toward the camera: back faces are never seen.
            primitive: wgpu::PrimitiveState {
                cull_mode: Some(wgpu::Face::Back),
                ..Default::default()
            },
            depth_stencil: Some(wgpu::DepthStencilState {
                format: DEPTH_FORMAT,
                depth_write_enabled: Some(true),
                depth_compare: Some(wgpu::CompareFunction::Less),
                // Each visible pixel keeps the stencil reference of its draw: its material class.
                stencil: wgpu::StencilState {
                    front: wgpu::StencilFaceState {
                        compare: wgpu::CompareFunction::Always,
                        fail_op: wgpu::StencilOperation::Keep,
                        depth_fail_op: wgpu::StencilOperation::Keep,
                        pass_op: wgpu::StencilOperation::Replace,
                    },
                    back: wgpu::StencilFaceState::IGNORE,
                    read_mask: 0xff,
                    write_mask: 0xff,
                },
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
        let uniform = |binding| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::FRAGMENT,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Uniform,
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
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
                uniform(0),
                uniform(1),
                uniform(2),
                uniform(3),
                uniform(4),
                wgpu::BindGroupLayoutEntry {
                    binding: 5,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Depth,
                        view_dimension: wgpu::TextureViewDimension::D2Array,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 6,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Comparison),
                    count: None,
                },
                texture(7),
                texture(8),
                texture(9),
            ],
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("light"),
            bind_group_layouts: &[Some(&light_layout)],
            immediate_size: 0,
        });
        // Two lighting pipelines: for Lambertian pixels (stencil 1) without the glossy code, and for
        // glossy pixels (stencil 2) with it; background pixels (0) run neither. Lavapipe runs both sides of a branch, so leaving the
        // glossy code out where k_s = 0 is the only way not to pay for it there.
        let light_pipeline = |glossy: bool| {
            let constants = [
                ("c_pcf_taps", pcf_taps as f64),
                ("c_glossy", glossy as u32 as f64),
            ];
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(if glossy {
                    "light glossy"
                } else {
                    "light diffuse"
                }),
                layout: Some(&layout),
                vertex: wgpu::VertexState {
                    module: &shader,
                    entry_point: Some("vs_light"),
                    compilation_options: Default::default(),
                    buffers: &[],
                },
                primitive: wgpu::PrimitiveState::default(),
                depth_stencil: Some(wgpu::DepthStencilState {
                    format: DEPTH_FORMAT,
                    depth_write_enabled: Some(false),
                    depth_compare: Some(wgpu::CompareFunction::Always),
                    stencil: wgpu::StencilState {
                        front: wgpu::StencilFaceState {
                            compare: wgpu::CompareFunction::Equal,
                            fail_op: wgpu::StencilOperation::Keep,
                            depth_fail_op: wgpu::StencilOperation::Keep,
                            pass_op: wgpu::StencilOperation::Keep,
                        },
                        back: wgpu::StencilFaceState::IGNORE,
                        read_mask: 0xff,
                        write_mask: 0,
                    },
                    bias: wgpu::DepthBiasState::default(),
                }),
                multisample: wgpu::MultisampleState::default(),
                fragment: Some(wgpu::FragmentState {
                    module: &shader,
                    entry_point: Some("fs_light"),
                    compilation_options: wgpu::PipelineCompilationOptions {
                        constants: &constants,
                        ..Default::default()
                    },
                    targets: &[Some(HDR_FORMAT.into())],
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        let light_pipelines = [light_pipeline(false), light_pipeline(true)];
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
            light_pipelines,
            light_layout,
            globals: uniform_buffer(device, "light globals", std::mem::size_of::<GlobalsRaw>()),
            lights: uniform_buffer(
                device,
                "lights",
                MAX_LIGHTS * std::mem::size_of::<LightRaw>(),
            ),
            groups: uniform_buffer(
                device,
                "groups",
                MAX_LIGHTS * std::mem::size_of::<GroupRaw>(),
            ),
            list: uniform_buffer(device, "draw light lists", MAX_LIST * 4),
            draws: uniform_buffer(device, "draws", MAX_DRAWS * 16),
            lists_fit: true,
            n_groups: 0,
            sampler,
            light_bind_group: None,
            bound_generation: u64::MAX,
            targets: Targets::new(device, size),
            light_raw: Vec::new(),
            group_raw: Vec::new(),
            lists_raw: Vec::new(),
            list_raw: Vec::new(),
            draw_raw: Vec::new(),
        }
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

    /// Uploads the lights (in group order) and each draw's list of groups; call when the lights
    /// change.
    pub fn upload_lights(
        &mut self,
        queue: &wgpu::Queue,
        lights: &[Light],
        grouping: &Grouping,
        draws: &[DrawRange],
    ) {
        self.light_raw.clear();
        self.light_raw.extend(
            grouping
                .order
                .iter()
                .map(|&i| LightRaw::from_light(&lights[i as usize])),
        );
        debug_assert!(self.light_raw.len() <= MAX_LIGHTS);
        self.light_raw.truncate(MAX_LIGHTS);
        draw_lists(
            draws,
            lights,
            grouping,
            &mut self.lists_raw,
            &mut self.list_raw,
        );
        self.lists_fit = self.list_raw.len() <= MAX_LIST;
        self.n_groups = grouping.groups.len() as u32;
        self.draw_raw.clear();
        self.draw_raw.extend(
            self.lists_raw
                .iter()
                .map(|&[offset, count]| [offset, count, 0, 0]),
        );
        queue.write_buffer(&self.draws, 0, bytemuck::cast_slice(&self.draw_raw));
        if !self.light_raw.is_empty() {
            queue.write_buffer(&self.lights, 0, bytemuck::cast_slice(&self.light_raw));
        }
        if self.lists_fit && !self.list_raw.is_empty() {
            queue.write_buffer(&self.list, 0, bytemuck::cast_slice(&self.list_raw));
        }
    }

    /// Uploads each group's shadow layer and projection; call when either changes.
    pub fn upload_groups(
        &mut self,
        queue: &wgpu::Queue,
        groups: &[Group],
        shadows: &[GroupShadow],
        fit: &ShadowFit,
    ) {
        self.group_raw.clear();
        self.group_raw
            .extend(groups.iter().zip(shadows).map(|(g, s)| GroupRaw {
                info: [s.layer, g.first, g.count, 0],
                rows: fit.texture_rows(s.axis),
            }));
        self.group_raw.truncate(MAX_LIGHTS);
        if !self.group_raw.is_empty() {
            queue.write_buffer(&self.groups, 0, bytemuck::cast_slice(&self.group_raw));
        }
    }

    /// Writes the per-frame uniforms.
    pub fn upload_globals(
        &self,
        queue: &wgpu::Queue,
        camera: &Camera,
        p: &ShadingParams,
        fit: &ShadowFit,
        texel_world: f32,
    ) {
        let (w, h) = self.targets.size;
        let view_proj = camera.view_proj(w as f32 / h as f32);
        queue.write_buffer(
            &self.camera,
            0,
            bytemuck::cast_slice(&view_proj.to_cols_array()),
        );
        let raw = GlobalsRaw {
            camera_pos: camera.eye.extend(1.0).to_array(),
            params: [
                p.exposure,
                p.glossy_threshold.unwrap_or(0.0),
                p.normal_offset * texel_world,
                1.0 / p.shadow_size as f32,
            ],
            flags: [
                (p.cull && self.lists_fit) as u32,
                p.glossy_threshold.is_some() as u32,
                0,
                self.n_groups,
            ],
            fit: fit.to_gpu(),
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
                    // The lighting pass reads the material classes.
                    stencil_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(0),
                        store: wgpu::StoreOp::Store,
                    }),
                }),
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&self.geometry_pipeline);
            pass.set_bind_group(0, &self.camera_bind_group, &[]);
            pass.set_vertex_buffer(0, scene.vertices.slice(..));
            pass.set_index_buffer(scene.indices.slice(..), wgpu::IndexFormat::Uint32);
            // One draw per normal bucket; the instance index tells the pixel its bucket.
            for (i, d) in scene.draws.iter().enumerate() {
                pass.set_stencil_reference(if d.glossy {
                    STENCIL_GLOSSY
                } else {
                    STENCIL_LAMBERTIAN
                });
                pass.draw_indexed(d.range.clone(), 0, i as u32..i as u32 + 1);
            }
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
                    buffer(1, &self.lights),
                    buffer(2, &self.groups),
                    buffer(3, &self.list),
                    buffer(4, &self.draws),
                    view(5, shadow_view),
                    wgpu::BindGroupEntry {
                        binding: 6,
                        resource: wgpu::BindingResource::Sampler(&self.sampler),
                    },
                    view(7, &self.targets.gbuffer[0]),
                    view(8, &self.targets.gbuffer[1]),
                    view(9, &self.targets.gbuffer[2]),
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
            // Read-only: the stencil selects the pixels of each pipeline.
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &self.targets.depth,
                depth_ops: None,
                stencil_ops: None,
            }),
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        pass.set_bind_group(0, &*bind_group, &[]);
        for (pipeline, reference) in self
            .light_pipelines
            .iter()
            .zip([STENCIL_LAMBERTIAN, STENCIL_GLOSSY])
        {
            pass.set_pipeline(pipeline);
            pass.set_stencil_reference(reference);
            pass.draw(0..3, 0..1);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::cluster::Clusterer;

    #[test]
    fn a_light_below_a_draws_cone_is_culled_and_one_above_is_kept() {
        let draws = [DrawRange {
            range: 0..3,
            axis: Vec3::Y,
            sin_alpha: 10f32.to_radians().sin(),
            glossy: false,
        }];
        let light = |id, d: Vec3| Light {
            id,
            to_light: d.normalize().to_array(),
            irradiance: [1.0; 3],
            solid_angle: 0.1,
            angular_radius: 0.0,
            extent: None,
            shadowed: None,
        };
        // 5° below the horizon: reaches normals tilted 10° toward it. 20° below: cannot.
        let lights = [
            light(0, Vec3::new(0.0, -(20f32.to_radians().tan()), 1.0)),
            light(1, Vec3::new(0.0, -(5f32.to_radians().tan()), 1.0)),
            light(2, Vec3::new(0.2, 1.0, 0.0)),
        ];
        let mut c = Clusterer::new(0.0);
        let mut g = Grouping::default();
        c.group(&lights, &mut g);
        let (mut lists, mut list) = (Vec::new(), Vec::new());
        draw_lists(&draws, &lights, &g, &mut lists, &mut list);
        let [off, n] = lists[0];
        assert_eq!(&list[off as usize..(off + n) as usize], &[1, 2]);
        assert_eq!(lists.last().unwrap()[1], 3);
    }
}
