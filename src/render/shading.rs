//! The shading pass: every pixel of the scene lit by the light groups, through their shadow maps,
//! into a linear HDR target (`shaders/shade.wgsl`); and the normal bins that cull lights per pixel.
//!
//! Input: the grouped lights ([`Grouping`]), each group's [`GroupShadow`], the camera. Output: the
//! HDR target (linear radiance × exposure, Rgba32Float) that the tonemap pass displays and the tests
//! read back.
//!
//! Culling by normal extent (ALGORITHMS.md §6): the unit sphere of normals is cut into B × B bins of
//! the octahedral map. A bin's normals lie in a cone (axis a, half-angle α), and a light can reach
//! one of them only if to_light·a > −sin α. Each bin gets the list of groups with such a member; a
//! pixel loops over its bin's list only. Lights below the surface are skipped per pixel anyway
//! (n·l ≤ 0); the bins save the loop over the other half of the set.

use super::cluster::{Group, Grouping};
use super::scene::{Camera, Vertex};
use super::shadow::{GroupShadow, SceneBuffers};
use crate::lights::Light;
use glam::{Vec2, Vec3};

/// Format of the HDR target.
pub const HDR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Float;
/// Format of the camera's depth buffer.
pub const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
/// Side B of the B × B grid of normal bins (64 cones of about 25°).
pub const BIN_SIDE: u32 = 8;

/// `Globals` in shade.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
struct GlobalsRaw {
    view_proj: [f32; 16],
    camera_pos: [f32; 4],
    params: [f32; 4],
    flags: [u32; 4],
}

/// `Light` in shade.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct LightRaw {
    to_light: [f32; 4],
    irradiance: [f32; 4],
}

impl LightRaw {
    pub fn from_light(l: &Light) -> LightRaw {
        let [x, y, z] = l.to_light;
        let [r, g, b] = l.irradiance;
        LightRaw {
            to_light: [x, y, z, 0.0],
            irradiance: [r, g, b, 0.0],
        }
    }
}

/// `Group` in shade.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
struct GroupRaw {
    view_proj: [f32; 16],
    layer: u32,
    first: u32,
    count: u32,
    pad: u32,
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

/// Octahedral map of a unit vector to [0,1]², +Y at the centre (matches `octahedral_encode` in
/// shade.wgsl).
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

/// Inverse of [`octahedral_encode`].
pub fn octahedral_decode(uv: Vec2) -> Vec3 {
    let p = uv * 2.0 - Vec2::ONE;
    let y = 1.0 - p.x.abs() - p.y.abs();
    let (x, z) = if y < 0.0 {
        // The lower hemisphere is folded over the square's corners; unfold it.
        (
            (1.0 - p.y.abs()) * p.x.signum(),
            (1.0 - p.x.abs()) * p.y.signum(),
        )
    } else {
        (p.x, p.y)
    };
    Vec3::new(x, y, z).normalize()
}

/// The cones of the B × B normal bins.
#[derive(Clone, Debug)]
pub struct NormalBins {
    side: u32,
    /// Per bin: the cone's axis and sin α.
    cones: Vec<(Vec3, f32)>,
}

impl NormalBins {
    pub fn new(side: u32) -> NormalBins {
        // Each bin is sampled on a 9 × 9 grid of its square (edges included); the cone is the
        // samples' mean direction and their largest angle from it, plus 2° for the gaps between
        // samples (about 3° apart at B = 8).
        const SAMPLES: u32 = 9;
        let margin = 2f32.to_radians();
        let mut cones = Vec::with_capacity((side * side) as usize);
        for j in 0..side {
            for i in 0..side {
                let dirs: Vec<Vec3> = (0..SAMPLES * SAMPLES)
                    .map(|k| {
                        let (a, b) = ((k % SAMPLES) as f32, (k / SAMPLES) as f32);
                        let s = (SAMPLES - 1) as f32;
                        octahedral_decode(Vec2::new(
                            (i as f32 + a / s) / side as f32,
                            (j as f32 + b / s) / side as f32,
                        ))
                    })
                    .collect();
                let axis = dirs.iter().sum::<Vec3>().normalize_or(Vec3::Y);
                let alpha = dirs
                    .iter()
                    .map(|d| axis.dot(*d).clamp(-1.0, 1.0).acos())
                    .fold(0.0f32, f32::max)
                    + margin;
                cones.push((axis, alpha.min(std::f32::consts::PI).sin()));
                if alpha >= std::f32::consts::FRAC_PI_2 {
                    // sin α is no longer monotonic past 90°: such a cone sees every light.
                    cones.last_mut().unwrap().1 = 1.0;
                }
            }
        }
        NormalBins { side, cones }
    }

    pub fn side(&self) -> u32 {
        self.side
    }

    /// Bin index of a normal, as shade.wgsl computes it.
    pub fn bin_of(&self, n: Vec3) -> usize {
        let uv = octahedral_encode(n) * self.side as f32;
        let i = (uv.x as u32).min(self.side - 1);
        let j = (uv.y as u32).min(self.side - 1);
        (j * self.side + i) as usize
    }

    /// Per bin (offset, count) into `list`, then one more entry listing every group.
    /// `culled_in` counts the (bin, group) pairs kept, for the statistics.
    pub fn lists(
        &self,
        lights: &[Light],
        grouping: &Grouping,
        bins: &mut Vec<[u32; 2]>,
        list: &mut Vec<u32>,
    ) {
        bins.clear();
        list.clear();
        for &(axis, sin_alpha) in &self.cones {
            let offset = list.len() as u32;
            for (gi, g) in grouping.groups.iter().enumerate() {
                let members = &grouping.order[g.first as usize..(g.first + g.count) as usize];
                let reaches = members.iter().any(|&i| {
                    Vec3::from_array(lights[i as usize].to_light).dot(axis) > -sin_alpha
                });
                if reaches {
                    list.push(gi as u32);
                }
            }
            bins.push([offset, list.len() as u32 - offset]);
        }
        let offset = list.len() as u32;
        list.extend(0..grouping.groups.len() as u32);
        bins.push([offset, grouping.groups.len() as u32]);
    }
}

/// A storage buffer that grows (by powers of two) to fit what is written to it.
struct GrowBuffer {
    label: &'static str,
    buffer: wgpu::Buffer,
}

impl GrowBuffer {
    fn new(device: &wgpu::Device, label: &'static str, size: u64) -> GrowBuffer {
        GrowBuffer {
            label,
            buffer: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: size.max(256),
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
        }
    }

    /// Writes `data`; returns true when the buffer had to be reallocated (rebind it).
    fn write(&mut self, device: &wgpu::Device, queue: &wgpu::Queue, data: &[u8]) -> bool {
        let grew = data.len() as u64 > self.buffer.size();
        if grew {
            *self = GrowBuffer::new(device, self.label, (data.len() as u64).next_power_of_two());
        }
        if !data.is_empty() {
            queue.write_buffer(&self.buffer, 0, data);
        }
        grew
    }
}

/// The shading pass and its targets.
pub struct ShadingPass {
    device: wgpu::Device,
    pipeline: wgpu::RenderPipeline,
    bind_group_layout: wgpu::BindGroupLayout,
    globals: wgpu::Buffer,
    lights: GrowBuffer,
    groups: GrowBuffer,
    bins: GrowBuffer,
    bin_groups: GrowBuffer,
    sampler: wgpu::Sampler,
    bind_group: Option<wgpu::BindGroup>,
    /// Shadow-array generation the bind group was made for.
    bound_generation: u64,
    pub hdr: wgpu::Texture,
    pub hdr_view: wgpu::TextureView,
    depth_view: wgpu::TextureView,
    pub size: (u32, u32),
    pub normal_bins: NormalBins,
    // CPU staging, reused between uploads.
    light_raw: Vec<LightRaw>,
    group_raw: Vec<GroupRaw>,
    bin_raw: Vec<[u32; 2]>,
    bin_list: Vec<u32>,
}

impl ShadingPass {
    pub fn new(device: &wgpu::Device, size: (u32, u32)) -> ShadingPass {
        let shader = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("shade.wgsl"),
            source: wgpu::ShaderSource::Wgsl(include_str!("../../shaders/shade.wgsl").into()),
        });
        let storage = |binding| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::FRAGMENT,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only: true },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let bind_group_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("shade"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: wgpu::BufferSize::new(
                            std::mem::size_of::<GlobalsRaw>() as u64
                        ),
                    },
                    count: None,
                },
                storage(1),
                storage(2),
                storage(3),
                storage(4),
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
            ],
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("shade"),
            bind_group_layouts: &[Some(&bind_group_layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("shade"),
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
                targets: &[Some(HDR_FORMAT.into())],
            }),
            multiview_mask: None,
            cache: None,
        });
        let globals = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("shade globals"),
            size: std::mem::size_of::<GlobalsRaw>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
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
        let (hdr, hdr_view, depth_view) = Self::targets(device, size);
        ShadingPass {
            device: device.clone(),
            pipeline,
            bind_group_layout,
            globals,
            lights: GrowBuffer::new(device, "lights", 64 * 32),
            groups: GrowBuffer::new(device, "groups", 64 * 80),
            bins: GrowBuffer::new(device, "normal bins", 8 * (BIN_SIDE * BIN_SIDE + 1) as u64),
            bin_groups: GrowBuffer::new(device, "bin groups", 4096),
            sampler,
            bind_group: None,
            bound_generation: u64::MAX,
            hdr,
            hdr_view,
            depth_view,
            size,
            normal_bins: NormalBins::new(BIN_SIDE),
            light_raw: Vec::new(),
            group_raw: Vec::new(),
            bin_raw: Vec::new(),
            bin_list: Vec::new(),
        }
    }

    fn targets(
        device: &wgpu::Device,
        (width, height): (u32, u32),
    ) -> (wgpu::Texture, wgpu::TextureView, wgpu::TextureView) {
        let extent = wgpu::Extent3d {
            width,
            height,
            depth_or_array_layers: 1,
        };
        let hdr = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("hdr"),
            size: extent,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: HDR_FORMAT,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT
                | wgpu::TextureUsages::TEXTURE_BINDING
                | wgpu::TextureUsages::COPY_SRC,
            view_formats: &[],
        });
        let depth = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("camera depth"),
            size: extent,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: DEPTH_FORMAT,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
            view_formats: &[],
        });
        let hdr_view = hdr.create_view(&Default::default());
        let depth_view = depth.create_view(&Default::default());
        (hdr, hdr_view, depth_view)
    }

    /// Rebuilds the size-dependent targets.
    pub fn resize(&mut self, size: (u32, u32)) {
        if size != self.size {
            (self.hdr, self.hdr_view, self.depth_view) = Self::targets(&self.device, size);
            self.size = size;
        }
    }

    /// Uploads the lights (in group order) and the normal bins' lists; call when the lights change.
    pub fn upload_lights(
        &mut self,
        queue: &wgpu::Queue,
        lights: &[Light],
        grouping: &Grouping,
    ) {
        self.light_raw.clear();
        self.light_raw.extend(
            grouping
                .order
                .iter()
                .map(|&i| LightRaw::from_light(&lights[i as usize])),
        );
        self.normal_bins
            .lists(lights, grouping, &mut self.bin_raw, &mut self.bin_list);
        let mut rebind = self
            .lights
            .write(&self.device, queue, bytemuck::cast_slice(&self.light_raw));
        rebind |= self
            .bins
            .write(&self.device, queue, bytemuck::cast_slice(&self.bin_raw));
        rebind |= self
            .bin_groups
            .write(&self.device, queue, bytemuck::cast_slice(&self.bin_list));
        if rebind {
            self.bind_group = None;
        }
    }

    /// Average length of the bins' group lists over the list of all groups (1 = no culling).
    pub fn mean_bin_fraction(&self) -> f32 {
        let Some(all) = self.bin_raw.last() else {
            return 1.0;
        };
        if all[1] == 0 || self.bin_raw.len() < 2 {
            return 1.0;
        }
        let bins = &self.bin_raw[..self.bin_raw.len() - 1];
        bins.iter().map(|b| b[1] as f32).sum::<f32>() / (bins.len() as f32 * all[1] as f32)
    }

    /// Uploads each group's shadow layer and matrix; call when either changes.
    pub fn upload_groups(&mut self, queue: &wgpu::Queue, groups: &[Group], shadows: &[GroupShadow]) {
        self.group_raw.clear();
        self.group_raw
            .extend(groups.iter().zip(shadows).map(|(g, s)| GroupRaw {
                view_proj: s.view_proj.to_cols_array(),
                layer: s.layer,
                first: g.first,
                count: g.count,
                pad: 0,
            }));
        if self
            .groups
            .write(&self.device, queue, bytemuck::cast_slice(&self.group_raw))
        {
            self.bind_group = None;
        }
    }

    /// Writes the per-frame uniforms.
    pub fn upload_globals(&self, queue: &wgpu::Queue, camera: &Camera, p: &ShadingParams, texel_world: f32) {
        let aspect = self.size.0 as f32 / self.size.1 as f32;
        let raw = GlobalsRaw {
            view_proj: camera.view_proj(aspect).to_cols_array(),
            camera_pos: camera.eye.extend(1.0).to_array(),
            params: [
                p.exposure,
                p.glossy_threshold.unwrap_or(0.0),
                p.normal_offset * texel_world,
                1.0 / p.shadow_size as f32,
            ],
            flags: [
                p.cull as u32,
                p.glossy_threshold.is_some() as u32,
                p.pcf_taps,
                BIN_SIDE,
            ],
        };
        queue.write_buffer(&self.globals, 0, bytemuck::bytes_of(&raw));
    }

    /// Records the pass.
    pub fn draw(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        scene: &SceneBuffers,
        shadow_view: &wgpu::TextureView,
        shadow_generation: u64,
    ) {
        if self.bound_generation != shadow_generation {
            self.bind_group = None;
        }
        let bind_group = self.bind_group.get_or_insert_with(|| {
            self.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("shade"),
                layout: &self.bind_group_layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: self.globals.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: self.lights.buffer.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 2,
                        resource: self.groups.buffer.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 3,
                        resource: self.bins.buffer.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 4,
                        resource: self.bin_groups.buffer.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 5,
                        resource: wgpu::BindingResource::TextureView(shadow_view),
                    },
                    wgpu::BindGroupEntry {
                        binding: 6,
                        resource: wgpu::BindingResource::Sampler(&self.sampler),
                    },
                ],
            })
        });
        self.bound_generation = shadow_generation;
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("shade pass"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: &self.hdr_view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                    store: wgpu::StoreOp::Store,
                },
            })],
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &self.depth_view,
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
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &*bind_group, &[]);
        pass.set_vertex_buffer(0, scene.vertices.slice(..));
        pass.set_index_buffer(scene.indices.slice(..), wgpu::IndexFormat::Uint32);
        // Casters come first in the index buffer: the mesh, in front, fills the depth buffer before
        // the ground behind it is shaded.
        pass.draw_indexed(scene.all.clone(), 0, 0..1);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn octahedral_round_trip() {
        for k in 0..500 {
            // Fibonacci sphere directions.
            let y = 1.0 - 2.0 * (k as f32 + 0.5) / 500.0;
            let phi = k as f32 * 2.399_963;
            let r = (1.0 - y * y).sqrt();
            let d = Vec3::new(r * phi.cos(), y, r * phi.sin());
            let uv = octahedral_encode(d);
            let back = octahedral_decode(uv);
            assert!(d.dot(back) > 0.99999, "{d} -> {uv} -> {back}");
        }
    }

    #[test]
    fn every_normal_lies_in_its_bins_cone() {
        let bins = NormalBins::new(BIN_SIDE);
        for k in 0..4000 {
            let y = 1.0 - 2.0 * (k as f32 + 0.5) / 4000.0;
            let phi = k as f32 * 2.399_963;
            let r = (1.0 - y * y).sqrt();
            let n = Vec3::new(r * phi.cos(), y, r * phi.sin());
            let (axis, sin_alpha) = bins.cones[bins.bin_of(n)];
            // n within α of the axis ⇔ n·a ≥ cos α.
            let cos_alpha = (1.0 - sin_alpha * sin_alpha).sqrt();
            assert!(sin_alpha >= 1.0 || n.dot(axis) >= cos_alpha - 1e-6, "{n} bin {}", bins.bin_of(n));
        }
    }

    #[test]
    fn a_light_below_a_bins_cone_is_culled_and_one_above_is_kept() {
        let bins = NormalBins::new(BIN_SIDE);
        let up = bins.bin_of(Vec3::Y);
        let light = |id, d: Vec3| Light {
            id,
            to_light: d.normalize().to_array(),
            irradiance: [1.0; 3],
            solid_angle: 0.1,
        };
        let lights = [light(0, Vec3::new(0.0, -1.0, 0.1)), light(1, Vec3::new(0.2, 1.0, 0.0))];
        let mut c = super::super::cluster::Clusterer::new(0.0);
        let mut g = Grouping::default();
        c.group(&lights, &mut g);
        let (mut b, mut l) = (Vec::new(), Vec::new());
        bins.lists(&lights, &g, &mut b, &mut l);
        let [off, n] = b[up];
        assert_eq!(&l[off as usize..(off + n) as usize], &[1]);
        assert_eq!(b.last().unwrap()[1], 2);
    }
}
