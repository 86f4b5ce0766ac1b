//! The renderer: owns the device state of every pass and draws one frame (ALGORITHMS.md §6).
//!
//! Input: a [`Scene`] (once), [`Light`]s (whenever a new set arrives, [`Renderer::set_lights`]) and
//! a [`Camera`] per frame. Output: the frame in a display target (the window's surface, or its own
//! texture headless, read back with [`Renderer::read_rgba8`] and [`Renderer::read_hdr`]) and what
//! it cost ([`FrameStats`]).
//!
//! A frame, in order: group the lights ([`cluster`](super::cluster)), (re)draw the shadow maps
//! that need it ([`shadow`](super::shadow); with a shadow budget, only the marked lights' groups
//! have maps), shade every pixel into a linear HDR target
//! ([`shading`]), tonemap it to the display ([`tonemap`](super::tonemap)) and draw
//! the [`overlay`](super::overlay). Everything is built in [`Renderer::new`]; [`Renderer::render`]
//! writes buffers and records passes, and uploads lights only when they changed (the shape of
//! wgpu's shadow example, STYLE.md §1).

use super::cluster::{Clusterer, Grouping};
use super::gpu::Gpu;
use super::overlay::{OverlayPass, Status};
use super::scene::{Camera, Scene, SceneBuffers};
use super::shading::{self, ShadingParams, ShadingPass};
use super::shadow::{GroupShadow, ShadowFit, ShadowMaps};
use super::tonemap::TonemapPass;
use crate::lights::Light;

/// Format of headless frames (PNG output, tests).
pub const OUTPUT_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8UnormSrgb;
/// Every format the renderer draws into, which [`Gpu::new`] checks the adapter can render to.
pub const TARGET_FORMATS: [wgpu::TextureFormat; 7] = [
    shading::GBUFFER_FORMATS[0],
    shading::GBUFFER_FORMATS[1],
    shading::GBUFFER_FORMATS[2],
    shading::HDR_FORMAT,
    shading::DEPTH_FORMAT,
    super::shadow::SHADOW_FORMAT,
    OUTPUT_FORMAT,
];

/// The renderer's switches; each cost saver of ALGORITHMS.md §6 can be turned off on its own.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Options {
    /// Cull lights per pixel by the pixel's normal bin.
    pub cull: bool,
    /// Glossy refinement: the glossy lobe only for lights where it is above this fraction of its peak
    /// (near the reflected view direction); `None` = full BRDF for every light.
    pub glossy_threshold: Option<f32>,
    /// Clustering radius δ in degrees (lights within δ share a shadow map); 0 = off.
    pub cluster_deg: f32,
    /// Reuse a shadow map while its light moved less than ε degrees; `None` = redraw every frame.
    pub reuse_deg: Option<f32>,
    /// Side of each shadow map, texels.
    pub shadow_size: u32,
    /// PCF taps per lookup: 1 (one bilinear 2 × 2 tap) or 4 (a 3 × 3 tent).
    pub pcf_taps: u32,
    /// Normal offset of shadow lookups, in shadow texels.
    pub normal_offset_texels: f32,
    /// Fixed exposure; `None` = from the lights (a grey ground under them at mid-grey).
    pub exposure: Option<f32>,
    /// Draw the overlay.
    pub overlay: bool,
}

impl Options {
    /// Every cost saver off: every light its own shadow map, every map drawn every frame, every
    /// light shaded at every pixel with the full BRDF.
    pub fn naive() -> Options {
        Options {
            cull: false,
            glossy_threshold: None,
            cluster_deg: 0.0,
            reuse_deg: None,
            shadow_size: 512,
            pcf_taps: 1,
            normal_offset_texels: 1.5,
            exposure: None,
            overlay: true,
        }
    }

    /// Every cost saver on, with the defaults of ALGORITHMS.md §6.
    pub fn optimised() -> Options {
        Options {
            cull: true,
            glossy_threshold: Some(0.01),
            cluster_deg: 3.0,
            reuse_deg: Some(0.5),
            ..Options::naive()
        }
    }
}

/// What a frame cost.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FrameStats {
    pub lights: u32,
    /// Shadow groups with a map (= shadow maps in use; a shadow budget's unshadowed lights are
    /// grouped without one).
    pub groups: u32,
    /// Shadow maps drawn this frame.
    pub maps_drawn: u32,
}

/// A headless target and the buffer it is read back through.
struct Output {
    texture: wgpu::Texture,
    view: wgpu::TextureView,
}

/// The passes and the per-frame state.
pub struct Renderer {
    device: wgpu::Device,
    queue: wgpu::Queue,
    pub options: Options,
    scene: SceneBuffers,
    shadows: ShadowMaps,
    shading: ShadingPass,
    tonemap: TonemapPass,
    overlay: OverlayPass,
    clusterer: Clusterer,
    lights: Vec<Light>,
    grouping: Grouping,
    group_shadows: Vec<GroupShadow>,
    lights_dirty: bool,
    exposure: f32,
    output: Option<Output>,
}

impl Renderer {
    /// Builds every pipeline and buffer. `format` is the display target's (the window's surface, or
    /// [`OUTPUT_FORMAT`] headless).
    pub fn new(
        gpu: &Gpu,
        scene: &Scene,
        size: (u32, u32),
        format: wgpu::TextureFormat,
        options: Options,
    ) -> Renderer {
        let device = gpu.device.clone();
        let scene_buffers = SceneBuffers::new(&device, scene);
        let shadows = ShadowMaps::new(gpu, ShadowFit::for_scene(scene), options.shadow_size);
        let shading = ShadingPass::new(&device, size, scene_buffers.draws.len(), options.pcf_taps);
        let tonemap = TonemapPass::new(&device, format, shading.hdr().1);
        let overlay = OverlayPass::new(&device, format);
        Renderer {
            queue: gpu.queue.clone(),
            options,
            scene: scene_buffers,
            shadows,
            shading,
            tonemap,
            overlay,
            clusterer: Clusterer::new(options.cluster_deg),
            lights: Vec::new(),
            grouping: Grouping::default(),
            group_shadows: Vec::new(),
            lights_dirty: true,
            exposure: options.exposure.unwrap_or(1.0),
            output: None,
            device,
        }
    }

    /// Changes the switches (shadow-map reuse starts over when grouping changes).
    pub fn set_options(&mut self, options: Options) {
        if options.cluster_deg != self.options.cluster_deg {
            self.clusterer = Clusterer::new(options.cluster_deg);
            self.shadows.invalidate();
        }
        if options.pcf_taps != self.options.pcf_taps {
            // The tap count is compiled into the lighting pipeline.
            self.shading = ShadingPass::new(
                &self.device,
                self.shading.size(),
                self.scene.draws.len(),
                options.pcf_taps,
            );
            self.tonemap.resize(self.shading.hdr().1);
        }
        if options.shadow_size != self.options.shadow_size {
            self.shadows.set_size(options.shadow_size);
        }
        self.options = options;
        self.lights_dirty = true;
        if let Some(e) = options.exposure {
            self.exposure = e;
        }
    }

    /// Takes a new set of lights (uploaded at the next frame).
    pub fn set_lights(&mut self, lights: &[Light]) {
        self.lights.clear();
        self.lights.extend_from_slice(lights);
        self.lights.sort_by_key(|l| l.id);
        // The uniform arrays hold MAX_LIGHTS; the progressive order makes the prefix the right cut.
        self.lights.truncate(shading::MAX_LIGHTS);
        self.lights_dirty = true;
        self.exposure = self
            .options
            .exposure
            .unwrap_or_else(|| auto_exposure(lights));
    }

    pub fn lights(&self) -> &[Light] {
        &self.lights
    }

    pub fn exposure(&self) -> f32 {
        self.exposure
    }

    /// Rebuilds the size-dependent targets.
    pub fn resize(&mut self, size: (u32, u32)) {
        if size != self.shading.size() {
            self.shading.resize(size);
            self.tonemap.resize(self.shading.hdr().1);
            self.output = None;
        }
    }

    pub fn size(&self) -> (u32, u32) {
        self.shading.size()
    }

    /// Renders one frame into `target` and submits it.
    pub fn render(
        &mut self,
        target: &wgpu::TextureView,
        camera: &Camera,
        status: &Status,
    ) -> FrameStats {
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("frame"),
            });
        let stats = self.encode(&mut encoder, target, camera, status);
        self.queue.submit([encoder.finish()]);
        stats
    }

    fn encode(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        target: &wgpu::TextureView,
        camera: &Camera,
        status: &Status,
    ) -> FrameStats {
        let o = self.options;
        if self.lights_dirty {
            self.clusterer.group(&self.lights, &mut self.grouping);
        }
        let reuse_cos = o.reuse_deg.map(|d| d.to_radians().cos());
        let maps_drawn = self.shadows.update(
            &self.queue,
            encoder,
            &self.scene,
            &self.grouping.groups,
            reuse_cos,
            &mut self.group_shadows,
        );
        if self.lights_dirty {
            self.shading.upload_lights(
                &self.queue,
                &self.lights,
                &self.grouping,
                &self.scene.draws,
            );
        }
        if self.lights_dirty || maps_drawn > 0 {
            self.shading.upload_groups(
                &self.queue,
                &self.grouping.groups,
                &self.group_shadows,
                &self.shadows.fit,
            );
        }
        self.lights_dirty = false;
        let params = ShadingParams {
            exposure: self.exposure,
            cull: o.cull,
            glossy_threshold: o.glossy_threshold,
            normal_offset: o.normal_offset_texels,
            shadow_size: self.shadows.size,
        };
        self.shading.upload_globals(
            &self.queue,
            camera,
            &params,
            &self.shadows.fit,
            self.shadows.fit.texel_world(self.shadows.size),
        );
        self.shading.draw(
            encoder,
            &self.scene,
            &self.shadows.array_view,
            self.shadows.generation,
        );
        let stats = FrameStats {
            lights: self.lights.len() as u32,
            groups: self.grouping.groups.iter().filter(|g| g.shadowed).count() as u32,
            maps_drawn,
        };
        if o.overlay {
            let marked = self.lights.iter().any(|l| l.shadowed.is_some());
            let status = Status {
                lights: self.lights.len(),
                maps_drawn,
                shadowed: marked.then(|| {
                    self.lights
                        .iter()
                        .filter(|l| l.shadowed == Some(true))
                        .count()
                }),
                ..*status
            };
            self.overlay
                .prepare(&self.queue, self.shading.size(), &self.lights, &status);
        }
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("display pass"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: target,
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
        self.tonemap.draw(&mut pass);
        if o.overlay {
            self.overlay.draw(&mut pass);
        }
        stats
    }

    /// Renders into the renderer's own target (headless; see [`Renderer::read_rgba8`]).
    pub fn render_headless(&mut self, camera: &Camera, status: &Status) -> FrameStats {
        let size = self.shading.size();
        let output = self.output.get_or_insert_with(|| {
            let texture = self.device.create_texture(&wgpu::TextureDescriptor {
                label: Some("headless output"),
                size: wgpu::Extent3d {
                    width: size.0,
                    height: size.1,
                    depth_or_array_layers: 1,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: OUTPUT_FORMAT,
                usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
                view_formats: &[],
            });
            let view = texture.create_view(&Default::default());
            Output { texture, view }
        });
        let view = output.view.clone();
        self.render(&view, camera, status)
    }

    /// Blocks until the device has finished all submitted work.
    pub fn wait(&self) {
        let _ = self.device.poll(wgpu::PollType::wait_indefinitely());
    }

    /// The last headless frame, 8-bit sRGB RGBA, rows top to bottom.
    pub fn read_rgba8(&self) -> image::RgbaImage {
        let output = self.output.as_ref().expect("render_headless first");
        let (w, h) = self.shading.size();
        let bytes = self.read_texture(&output.texture, 4);
        image::RgbaImage::from_raw(w, h, bytes).expect("size matches")
    }

    /// The last frame's linear HDR target (radiance × exposure), RGBA f32, rows top to bottom.
    pub fn read_hdr(&self) -> Vec<[f32; 4]> {
        let bytes = self.read_texture(self.shading.hdr().0, 16);
        bytemuck::pod_collect_to_vec(&bytes)
    }

    /// Copies a texture to the CPU (rows padded to 256 bytes on the way, unpadded here).
    fn read_texture(&self, texture: &wgpu::Texture, bytes_per_pixel: u32) -> Vec<u8> {
        let (w, h) = self.shading.size();
        let row = w * bytes_per_pixel;
        let padded =
            row.div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT) * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
        let buffer = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: (padded * h) as u64,
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("readback"),
            });
        encoder.copy_texture_to_buffer(
            texture.as_image_copy(),
            wgpu::TexelCopyBufferInfo {
                buffer: &buffer,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(padded),
                    rows_per_image: Some(h),
                },
            },
            wgpu::Extent3d {
                width: w,
                height: h,
                depth_or_array_layers: 1,
            },
        );
        self.queue.submit([encoder.finish()]);
        let slice = buffer.slice(..);
        slice.map_async(wgpu::MapMode::Read, |r| {
            r.expect("mapping the readback buffer")
        });
        self.wait();
        let data = slice.get_mapped_range().expect("mapped");
        let mut out = Vec::with_capacity((row * h) as usize);
        for y in 0..h as usize {
            out.extend_from_slice(&data[y * padded as usize..y * padded as usize + row as usize]);
        }
        drop(data);
        buffer.unmap();
        out
    }
}

/// An exposure that puts a grey (ρ = 0.5) horizontal surface under the lights at about 45 % of the
/// display's range after the tonemap: radiance 0.5/π · E_up, where E_up = Σ E_k · max(0, l_k.y).
pub fn auto_exposure(lights: &[Light]) -> f32 {
    let e_up: f32 = lights
        .iter()
        .map(|l| {
            let [r, g, b] = l.irradiance;
            (0.2126 * r + 0.7152 * g + 0.0722 * b) * l.to_light[1].max(0.0)
        })
        .sum();
    let radiance = 0.5 / std::f32::consts::PI * e_up;
    // 1 − exp(−x) = 0.45 at x ≈ 0.6.
    if radiance > 0.0 && radiance.is_finite() {
        0.6 / radiance
    } else {
        1.0
    }
}
