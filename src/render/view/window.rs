//! The windowed viewer (winit 0.30): the same [`Renderer`] drawing into a window's surface, with the
//! lights polled from the feed before every frame (the stream never blocks the window).
//!
//! Input: [`ViewArgs`]. Output: a window; closes on Escape or the window's close button.

use super::adaptive::LightState;
use super::args::{ViewArgs, camera_at};
use super::source::LightFeed;
use crate::render::gpu::Gpu;
use crate::render::overlay::Status;
use crate::render::renderer::{Options, Renderer, TARGET_FORMATS};
use crate::render::scene::Scene;
use std::sync::Arc;
use std::time::Instant;
use winit::application::ApplicationHandler;
use winit::event::{ElementState, KeyEvent, WindowEvent};
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::keyboard::{Key, NamedKey};
use winit::window::{Window, WindowId};

/// Everything that exists once the window does.
struct Live {
    window: Arc<Window>,
    surface: wgpu::Surface<'static>,
    config: wgpu::SurfaceConfiguration,
    gpu: Gpu,
    renderer: Renderer,
}

struct App {
    args: ViewArgs,
    options: Options,
    scene: Scene,
    feed: LightFeed,
    lights: LightState,
    live: Option<Live>,
    start: Instant,
    last_frame: Instant,
    /// Smoothed frame time, ms.
    frame_ms: Option<f32>,
    /// Set when something failed inside the event loop; returned by [`run`].
    error: Option<anyhow::Error>,
}

/// The window's size unless `--size` says otherwise (shadow maps are sized for it, see
/// `shadow::shadow_size_for`; a later resize keeps them).
const DEFAULT_SIZE: (u32, u32) = (960, 540);

/// Opens the window and runs until it is closed.
pub(super) fn run(args: ViewArgs) -> anyhow::Result<()> {
    let feed = args.feed()?;
    let scene = args.scene()?;
    let event_loop = EventLoop::new()
        .map_err(|e| anyhow::anyhow!("cannot open a window ({e}); try --headless"))?;
    event_loop.set_control_flow(ControlFlow::Poll);
    let mut app = App {
        options: args.options(args.size.unwrap_or(DEFAULT_SIZE)),
        lights: LightState::new(args.target_fps, args.lights),
        scene,
        feed,
        args,
        live: None,
        start: Instant::now(),
        last_frame: Instant::now(),
        frame_ms: None,
        error: None,
    };
    event_loop.run_app(&mut app)?;
    match app.error {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

impl App {
    fn open(&mut self, event_loop: &ActiveEventLoop) -> anyhow::Result<Live> {
        let (w, h) = self.args.size.unwrap_or(DEFAULT_SIZE);
        let window = Arc::new(
            event_loop.create_window(
                Window::default_attributes()
                    .with_title("vemlight view")
                    .with_inner_size(winit::dpi::PhysicalSize::new(w, h)),
            )?,
        );
        let backends = Gpu::backends(self.args.backend);
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor {
            backends,
            ..wgpu::InstanceDescriptor::new_with_display_handle(Box::new(
                event_loop.owned_display_handle(),
            ))
        });
        let surface = instance.create_surface(window.clone())?;
        let gpu = Gpu::with_instance(instance, backends, Some(&surface), &TARGET_FORMATS)?;
        eprintln!("vemlight view: {}", gpu.describe());
        let size = window.inner_size();
        let mut config = surface
            .get_default_config(&gpu.adapter, size.width.max(1), size.height.max(1))
            .ok_or_else(|| anyhow::anyhow!("the adapter cannot present to this window"))?;
        // Prefer an sRGB format so the tonemapped values are encoded on store, as headless.
        let caps = surface.get_capabilities(&gpu.adapter);
        if let Some(f) = caps.formats.iter().find(|f| f.is_srgb()) {
            config.format = *f;
        }
        config.present_mode = wgpu::PresentMode::AutoNoVsync;
        surface.configure(&gpu.device, &config);
        let renderer = Renderer::new(
            &gpu,
            &self.scene,
            (config.width, config.height),
            config.format,
            self.options,
        );
        Ok(Live {
            window,
            surface,
            config,
            gpu,
            renderer,
        })
    }

    fn frame(&mut self) {
        let Some(live) = &mut self.live else { return };
        if let Some(set) = self.feed.poll() {
            self.lights.set(&mut live.renderer, &set.lights);
        }
        if let Some(line) = self.feed.drop_report() {
            eprintln!("vemlight view: {line}");
        }
        let texture = match live.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(t)
            | wgpu::CurrentSurfaceTexture::Suboptimal(t) => t,
            wgpu::CurrentSurfaceTexture::Timeout | wgpu::CurrentSurfaceTexture::Occluded => return,
            _ => {
                // Outdated or lost: reconfigure and try at the next redraw.
                live.surface.configure(&live.gpu.device, &live.config);
                return;
            }
        };
        let view = texture.texture.create_view(&Default::default());
        let t = self.start.elapsed().as_secs_f32();
        let status = Status {
            fps: self.frame_ms.map(|ms| 1e3 / ms.max(1e-3)),
            stale: self.feed.is_stale(),
            ..Status::default()
        };
        let camera = camera_at(&self.args, &self.scene, t);
        live.renderer.render(&view, &camera, &status);
        live.window.pre_present_notify();
        live.gpu.queue.present(texture);
        let now = Instant::now();
        let ms = (now - self.last_frame).as_secs_f32() * 1e3;
        self.last_frame = now;
        self.frame_ms = Some(match self.frame_ms {
            Some(m) => 0.9 * m + 0.1 * ms,
            None => ms,
        });
        self.lights.frame_time(&mut live.renderer, ms);
    }
}

impl ApplicationHandler for App {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.live.is_some() {
            return;
        }
        match self.open(event_loop) {
            Ok(live) => {
                self.live = Some(live);
                self.last_frame = Instant::now();
            }
            Err(e) => {
                self.error = Some(e);
                event_loop.exit();
            }
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        match event {
            WindowEvent::CloseRequested
            | WindowEvent::KeyboardInput {
                event:
                    KeyEvent {
                        logical_key: Key::Named(NamedKey::Escape),
                        state: ElementState::Pressed,
                        ..
                    },
                ..
            } => event_loop.exit(),
            WindowEvent::Resized(size) => {
                if let Some(live) = &mut self.live
                    && size.width > 0
                    && size.height > 0
                {
                    live.config.width = size.width;
                    live.config.height = size.height;
                    live.surface.configure(&live.gpu.device, &live.config);
                    live.renderer.resize((size.width, size.height));
                }
            }
            WindowEvent::RedrawRequested => self.frame(),
            _ => {}
        }
    }

    fn about_to_wait(&mut self, _event_loop: &ActiveEventLoop) {
        if let Some(live) = &self.live {
            live.window.request_redraw();
        }
    }
}
