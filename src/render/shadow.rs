//! Shadow maps: one orthographic depth map per light group, in one depth texture array
//! (ALGORITHMS.md §6), with reuse while a group's direction stays put.
//!
//! Input: the frame's [`Group`]s (a direction and a stable key each) and the shadow casters of the
//! scene's device buffers ([`SceneBuffers`]). Output: per group a [`GroupShadow`] (its layer and the
//! direction the layer was drawn from; the projection follows from that and the [`ShadowFit`]) for
//! the shading pass to sample with, and the depth passes that (re)draw the layers that need it.
//! Uses `scene`, `cluster` and `gpu`.
//!
//! A layer is redrawn when its group is new, when reuse is off, or when the group's axis has moved
//! more than ε since the layer was drawn; otherwise the old map and its old direction stay in use,
//! which is exact for a steady light and off by at most ε for a moving one.

use super::cluster::Group;
use super::gpu::Gpu;
use super::scene::{Scene, SceneBuffers, Vertex};
use glam::Vec3;
use std::collections::HashMap;

/// The default side of the shadow maps for a frame of `width` × `height` pixels: the largest power of
/// two not above the longer side, within 256–2048. The maps are fitted to the casters, which cover
/// part of the frame, so this gives at least one texel per pixel on them; more texels than pixels
/// buy no visible detail, and every lighting pass reads every map, so the texels a frame touches
/// cost memory traffic (on lavapipe the shadow lookups wait on their gathers).
pub fn shadow_size_for(width: u32, height: u32) -> u32 {
    let longer = width.max(height).max(1);
    (1u32 << (31 - longer.leading_zeros())).clamp(256, 2048)
}

/// Depth format of the shadow maps.
pub const SHADOW_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
/// "This group has no shadow map" (more groups than the device allows layers, or a group a shadow
/// budget leaves unshadowed): shaded as lit.
pub const NO_LAYER: u32 = u32::MAX;
/// Smallest array allocated (layers); it grows by powers of two as groups appear.
const MIN_LAYERS: u32 = 8;

/// Where a group's shadow comes from this frame: a layer, and the direction it was drawn from (the
/// projection follows from it and the [`ShadowFit`], in the shaders' `shadow_clip`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GroupShadow {
    pub layer: u32,
    pub axis: Vec3,
}

/// What a layer of the array holds.
#[derive(Clone, Copy, Debug)]
struct Layer {
    key: u32,
    /// The axis the map was drawn from.
    drawn_axis: Vec3,
    /// Last frame that used it (layers unused this frame may be given to new groups).
    used: u64,
}

/// The orthographic volume every shadow map covers: the casters' bounding sphere, seen along the light.
#[derive(Clone, Copy, Debug)]
pub struct ShadowFit {
    /// Centre and radius of the casters' bounding sphere.
    pub centre: Vec3,
    pub radius: f32,
    /// Distance from `centre` to the farthest point of the whole scene (the far plane must reach it).
    pub reach: f32,
}

impl ShadowFit {
    pub fn for_scene(scene: &Scene) -> ShadowFit {
        let b = if scene.caster_bounds.is_empty() {
            scene.bounds
        } else {
            scene.caster_bounds
        };
        let centre = b.centre();
        let corners = [scene.bounds.min, scene.bounds.max];
        let mut reach = b.radius();
        for i in 0..8 {
            let c = Vec3::new(
                corners[i & 1].x,
                corners[(i >> 1) & 1].y,
                corners[(i >> 2) & 1].z,
            );
            reach = reach.max(c.distance(centre));
        }
        ShadowFit {
            centre,
            radius: b.radius().max(1e-4),
            reach,
        }
    }

    /// World → shadow clip (wgpu NDC, z in [0, 1]) of an orthographic view along `-to_light`, fitted
    /// to the casters' sphere across, and in depth from the sphere's light-side edge to `reach`
    /// beyond its centre. The sphere does not change with the direction, so a map's texel size is
    /// the same for all lights. `shadow_clip` in shaders/shadow.wgsl and shaders/light.wgsl computes
    /// the same; this copy is for tests.
    ///
    /// With d = p − centre, image axes x̂ = normalize(up × a), ŷ = a × x̂ (up = +Y, or +Z for a light
    /// within 8° of the zenith or nadir): x = x̂·d / r, y = ŷ·d / r, depth = (r − a·d) / (r + reach).
    pub fn project(&self, to_light: Vec3, p: Vec3) -> Vec3 {
        let up = if to_light.y.abs() > 0.99 {
            Vec3::Z
        } else {
            Vec3::Y
        };
        let x_axis = up.cross(to_light).normalize();
        let y_axis = to_light.cross(x_axis);
        let d = p - self.centre;
        let r = self.radius;
        Vec3::new(
            x_axis.dot(d) / r,
            y_axis.dot(d) / r,
            (r - to_light.dot(d)) / (r + self.reach),
        )
    }

    /// [`project`](Self::project) for one direction as an affine map straight to the shadow
    /// texture: rows (u, v, depth) such that u = row·(p, 1) with u, v in texture coordinates
    /// (x·½ + ½, −y·½ + ½). The lighting pass reads these three rows per group instead of deriving
    /// the image axes at every pixel.
    pub fn texture_rows(&self, to_light: Vec3) -> [[f32; 4]; 3] {
        let up = if to_light.y.abs() > 0.99 {
            Vec3::Z
        } else {
            Vec3::Y
        };
        let x_axis = up.cross(to_light).normalize();
        let y_axis = to_light.cross(x_axis);
        let (c, r) = (self.centre, self.radius);
        let u = x_axis * (0.5 / r);
        let v = y_axis * (-0.5 / r);
        let d = to_light * (-1.0 / (r + self.reach));
        [
            u.extend(0.5 - u.dot(c)).to_array(),
            v.extend(0.5 - v.dot(c)).to_array(),
            d.extend(r / (r + self.reach) - d.dot(c)).to_array(),
        ]
    }

    /// The fit as the shaders read it: (centre, radius), (reach, 0, 0, 0).
    pub fn to_gpu(&self) -> [[f32; 4]; 2] {
        [
            self.centre.extend(self.radius).to_array(),
            [self.reach, 0.0, 0.0, 0.0],
        ]
    }

    /// One shadow texel, in world units across.
    pub fn texel_world(&self, size: u32) -> f32 {
        2.0 * self.radius / size as f32
    }
}

/// The shadow-map array, its depth pass, and the cache of which group holds which layer.
pub struct ShadowMaps {
    device: wgpu::Device,
    pipeline: wgpu::RenderPipeline,
    bind_group_layout: wgpu::BindGroupLayout,
    /// Side of each (square) map, texels.
    pub size: u32,
    /// Layers allocated; see [`MIN_LAYERS`].
    capacity: u32,
    /// The device's array-layer limit.
    max_layers: u32,
    /// GL turns a square array whose layer count is a multiple of 6 into a cube map (STACK.md).
    pad_for_gl: bool,
    texture: wgpu::Texture,
    /// All layers, for sampling.
    pub array_view: wgpu::TextureView,
    /// One view per layer, as depth attachment.
    layer_views: Vec<wgpu::TextureView>,
    /// One direction per layer (xyz), read by `vs_shadow`.
    views_buf: wgpu::Buffer,
    /// The fit, read by `vs_shadow`.
    fit_buf: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    pub fit: ShadowFit,
    layers: Vec<Option<Layer>>,
    layer_of_key: HashMap<u32, u32>,
    /// Incremented each time the array is reallocated (the shading pass rebinds it).
    pub generation: u64,
    frame: u64,
    // Per-frame scratch.
    redraw: Vec<u32>,
}

impl ShadowMaps {
    pub fn new(gpu: &Gpu, fit: ShadowFit, size: u32) -> ShadowMaps {
        let device = gpu.device.clone();
        let shader = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("shadow.wgsl"),
            source: wgpu::ShaderSource::Wgsl(include_str!("../../shaders/shadow.wgsl").into()),
        });
        let bind_group_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("shadow"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::VERTEX,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Storage { read_only: true },
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::VERTEX,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: wgpu::BufferSize::new(32),
                    },
                    count: None,
                },
            ],
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("shadow"),
            bind_group_layouts: &[Some(&bind_group_layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("shadow"),
            layout: Some(&layout),
            vertex: wgpu::VertexState {
                module: &shader,
                entry_point: Some("vs_shadow"),
                compilation_options: Default::default(),
                buffers: &[Some(wgpu::VertexBufferLayout {
                    array_stride: std::mem::size_of::<Vertex>() as u64,
                    step_mode: wgpu::VertexStepMode::Vertex,
                    attributes: &wgpu::vertex_attr_array![0 => Float32x3],
                })],
            },
            // The casters are closed: their faces toward the light hold the nearest depth, so the
            // back faces can be culled (half the triangle setup, the bulk of a shadow pass here).
            primitive: wgpu::PrimitiveState {
                cull_mode: Some(wgpu::Face::Back),
                ..Default::default()
            },
            depth_stencil: Some(wgpu::DepthStencilState {
                format: SHADOW_FORMAT,
                depth_write_enabled: Some(true),
                depth_compare: Some(wgpu::CompareFunction::LessEqual),
                stencil: wgpu::StencilState::default(),
                bias: wgpu::DepthBiasState {
                    constant: 2,      // a couple of depth ulps against acne on surfaces facing the light
                    slope_scale: 2.0, // and more where the surface is steep to the light
                    clamp: 0.0,
                },
            }),
            multisample: wgpu::MultisampleState::default(),
            fragment: None,
            multiview_mask: None,
            cache: None,
        });
        let max_layers = gpu.max_layers;
        let pad_for_gl = gpu.is_gl();
        let fit_buf = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("shadow fit"),
            size: 32,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        gpu.queue
            .write_buffer(&fit_buf, 0, bytemuck::cast_slice(&fit.to_gpu()));
        let (texture, array_view, layer_views, views_buf, bind_group) = Self::allocate(
            &device,
            &bind_group_layout,
            &fit_buf,
            size,
            MIN_LAYERS,
            pad_for_gl,
        );
        ShadowMaps {
            device,
            pipeline,
            bind_group_layout,
            size,
            capacity: MIN_LAYERS,
            max_layers,
            pad_for_gl,
            texture,
            array_view,
            layer_views,
            views_buf,
            fit_buf,
            bind_group,
            fit,
            layers: vec![None; MIN_LAYERS as usize],
            layer_of_key: HashMap::new(),
            generation: 0,
            frame: 0,
            redraw: Vec::new(),
        }
    }

    #[allow(clippy::type_complexity)]
    fn allocate(
        device: &wgpu::Device,
        bgl: &wgpu::BindGroupLayout,
        fit_buf: &wgpu::Buffer,
        size: u32,
        layers: u32,
        pad_for_gl: bool,
    ) -> (
        wgpu::Texture,
        wgpu::TextureView,
        Vec<wgpu::TextureView>,
        wgpu::Buffer,
        wgpu::BindGroup,
    ) {
        // Pad 6k layers to 6k + 1 on GL, where they would otherwise become a cube map.
        let allocated = if pad_for_gl && layers.is_multiple_of(6) {
            layers + 1
        } else {
            layers
        };
        let texture = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("shadow maps"),
            size: wgpu::Extent3d {
                width: size,
                height: size,
                depth_or_array_layers: allocated,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: SHADOW_FORMAT,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
            view_formats: &[],
        });
        let array_view = texture.create_view(&wgpu::TextureViewDescriptor {
            label: Some("shadow maps"),
            dimension: Some(wgpu::TextureViewDimension::D2Array),
            ..Default::default()
        });
        let layer_views = (0..layers)
            .map(|i| {
                texture.create_view(&wgpu::TextureViewDescriptor {
                    label: Some("shadow map layer"),
                    dimension: Some(wgpu::TextureViewDimension::D2),
                    base_array_layer: i,
                    array_layer_count: Some(1),
                    ..Default::default()
                })
            })
            .collect();
        let views_buf = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("shadow views"),
            size: layers as u64 * 16,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("shadow"),
            layout: bgl,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: views_buf.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: fit_buf.as_entire_binding(),
                },
            ],
        });
        (texture, array_view, layer_views, views_buf, bind_group)
    }

    /// Reallocates the array for at least `needed` layers (all maps are lost and will be redrawn).
    fn grow(&mut self, needed: u32) {
        let capacity = needed
            .next_power_of_two()
            .max(MIN_LAYERS)
            .min(self.max_layers);
        if capacity <= self.capacity {
            return;
        }
        let (texture, array_view, layer_views, views_buf, bind_group) = Self::allocate(
            &self.device,
            &self.bind_group_layout,
            &self.fit_buf,
            self.size,
            capacity,
            self.pad_for_gl,
        );
        self.texture.destroy();
        self.texture = texture;
        self.array_view = array_view;
        self.layer_views = layer_views;
        self.views_buf = views_buf;
        self.bind_group = bind_group;
        self.capacity = capacity;
        self.layers = vec![None; capacity as usize];
        self.layer_of_key.clear();
        self.generation += 1;
    }

    /// Reallocates the maps at another resolution (all are redrawn).
    pub fn set_size(&mut self, size: u32) {
        if size == self.size {
            return;
        }
        self.size = size;
        let capacity = self.capacity;
        self.capacity = 0;
        self.grow(capacity);
    }

    /// Forgets every map (the next frame redraws them all).
    pub fn invalidate(&mut self) {
        self.layers.iter_mut().for_each(|l| *l = None);
        self.layer_of_key.clear();
    }

    /// Chooses a layer and a matrix for each group, and records the depth passes of the layers that
    /// must be (re)drawn into `encoder`. `reuse_cos`: cos ε, or `None` to redraw every map.
    /// Returns how many maps were drawn.
    pub fn update(
        &mut self,
        queue: &wgpu::Queue,
        encoder: &mut wgpu::CommandEncoder,
        scene: &SceneBuffers,
        groups: &[Group],
        reuse_cos: Option<f32>,
        out: &mut Vec<GroupShadow>,
    ) -> u32 {
        self.frame += 1;
        let frame = self.frame;
        let mapped = groups.iter().filter(|g| g.shadowed).count() as u32;
        if mapped > self.capacity {
            self.grow(mapped);
        }
        out.clear();
        self.redraw.clear();
        // Pass 1: groups that already hold a layer keep it; groups a shadow budget leaves
        // unshadowed get none (their keys are another clusterer's, so they are not looked up).
        out.extend(groups.iter().map(|g| match self.layer_of_key.get(&g.key) {
            Some(&layer) if g.shadowed => {
                let l = self.layers[layer as usize].as_mut().expect("mapped layer");
                l.used = frame;
                GroupShadow {
                    layer,
                    axis: l.drawn_axis,
                }
            }
            _ => GroupShadow {
                layer: NO_LAYER,
                axis: g.axis,
            },
        }));
        // Pass 2: new groups take a free layer, or one no group used this frame.
        let mut cursor = 0usize;
        for (g, s) in groups.iter().zip(out.iter_mut()) {
            if s.layer != NO_LAYER || !g.shadowed {
                continue;
            }
            while cursor < self.layers.len() && self.layers[cursor].is_some_and(|l| l.used == frame)
            {
                cursor += 1;
            }
            if cursor == self.layers.len() {
                break; // more groups than the device allows layers: the rest stay unshadowed
            }
            if let Some(old) = self.layers[cursor] {
                self.layer_of_key.remove(&old.key);
            }
            self.layers[cursor] = Some(Layer {
                key: g.key,
                drawn_axis: g.axis,
                used: frame,
            });
            self.layer_of_key.insert(g.key, cursor as u32);
            *s = GroupShadow {
                layer: cursor as u32,
                axis: g.axis,
            };
            self.redraw.push(cursor as u32);
        }
        // Pass 3: kept layers whose group moved more than ε (or every one, without reuse) are redrawn.
        for (g, s) in groups.iter().zip(out.iter_mut()) {
            if s.layer == NO_LAYER || self.redraw.contains(&s.layer) {
                continue;
            }
            let l = self.layers[s.layer as usize]
                .as_mut()
                .expect("mapped layer");
            let stale = match reuse_cos {
                Some(cos_eps) => l.drawn_axis.dot(g.axis) < cos_eps,
                None => true,
            };
            if stale {
                l.drawn_axis = g.axis;
                s.axis = g.axis;
                self.redraw.push(s.layer);
            }
        }
        // Record the depth passes.
        for &layer in &self.redraw {
            let axis = self.layers[layer as usize].expect("drawn layer").drawn_axis;
            queue.write_buffer(
                &self.views_buf,
                layer as u64 * 16,
                bytemuck::bytes_of(&axis.extend(0.0).to_array()),
            );
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("shadow pass"),
                color_attachments: &[],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &self.layer_views[layer as usize],
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(1.0),
                        store: wgpu::StoreOp::Store,
                    }),
                    stencil_ops: None,
                }),
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &self.bind_group, &[]);
            pass.set_vertex_buffer(0, scene.vertices.slice(..));
            pass.set_index_buffer(scene.indices.slice(..), wgpu::IndexFormat::Uint32);
            pass.draw_indexed(scene.casters.clone(), 0, layer..layer + 1);
        }
        self.redraw.len() as u32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shadow_size_follows_the_frame() {
        assert_eq!(shadow_size_for(320, 240), 256);
        assert_eq!(shadow_size_for(640, 480), 512);
        assert_eq!(shadow_size_for(960, 540), 512);
        assert_eq!(shadow_size_for(1920, 1080), 1024);
        assert_eq!(shadow_size_for(8000, 8000), 2048);
        assert_eq!(shadow_size_for(16, 16), 256);
    }

    #[test]
    fn texture_rows_agree_with_project() {
        let fit = ShadowFit {
            centre: Vec3::new(0.3, 0.5, -0.2),
            radius: 1.7,
            reach: 2.9,
        };
        for to_light in [
            Vec3::new(0.3, 0.8, -0.5).normalize(),
            Vec3::Y,
            Vec3::new(-0.9, 0.1, 0.4).normalize(),
        ] {
            let rows = fit.texture_rows(to_light);
            for p in [
                Vec3::ZERO,
                Vec3::new(1.0, -0.4, 2.0),
                Vec3::new(-1.5, 1.2, 0.1),
            ] {
                let clip = fit.project(to_light, p);
                let expected = [0.5 + 0.5 * clip.x, 0.5 - 0.5 * clip.y, clip.z];
                for (row, e) in rows.iter().zip(expected) {
                    let got = Vec3::from_slice(&row[..3]).dot(p) + row[3];
                    assert!((got - e).abs() < 1e-5, "{to_light} {p}: {got} vs {e}");
                }
            }
        }
    }

    #[test]
    fn the_fit_holds_the_casters_sphere_for_any_direction() {
        let fit = ShadowFit {
            centre: Vec3::new(0.0, 0.5, 0.0),
            radius: 1.0,
            reach: 4.0,
        };
        for d in [
            Vec3::Y,
            Vec3::new(0.3, 0.9, -0.2).normalize(),
            Vec3::new(1.0, -0.1, 0.0).normalize(),
        ] {
            for p in [
                fit.centre,
                fit.centre + 0.99 * Vec3::X,
                fit.centre - 0.99 * Vec3::Z,
                fit.centre + 0.99 * d,
            ] {
                let c = fit.project(d, p);
                assert!(
                    c.x.abs() <= 1.0 && c.y.abs() <= 1.0 && (0.0..=1.0).contains(&c.z),
                    "{d} {p} → {c}"
                );
            }
            // Toward the light is nearer (smaller depth).
            let near = fit.project(d, fit.centre + 0.5 * d).z;
            let far = fit.project(d, fit.centre - 0.5 * d).z;
            assert!(near < far);
            // A receiver `reach` away on the far side is still inside the depth range.
            assert!(fit.project(d, fit.centre - 3.9 * d).z <= 1.0);
            // Moving across the light direction moves across the map, not in depth.
            let side = d.cross(Vec3::new(0.3, 0.1, 0.9)).normalize();
            let a = fit.project(d, fit.centre);
            let b = fit.project(d, fit.centre + 0.5 * side);
            assert!((a.z - b.z).abs() < 1e-6 && (b.truncate() - a.truncate()).length() > 0.49);
        }
    }
}
