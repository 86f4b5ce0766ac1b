//! The graphics device: instance, adapter, device and queue, with the limits the renderer needs.
//!
//! Input: which backends to try ([`Backends`], from `--backend` or `WGPU_BACKEND`) and, for a window,
//! a surface to be compatible with. Output: a [`Gpu`], or a [`GpuError`] that says what to install or
//! change, never a panic: a machine with no adapter gets a clear message and a non-zero exit
//! (DESIGN.md, "Real parts": the software driver lavapipe is enough).

use std::fmt;
use wgpu::Backends;

/// Why no device could be had.
#[derive(Debug)]
pub enum GpuError {
    /// No adapter on any of the backends tried.
    NoAdapter { backends: Backends },
    /// An adapter was found but refused the device (limits or features).
    Device(String),
    /// The adapter cannot render to a texture format the renderer draws into (some GL drivers
    /// cannot render to 32-bit float colour targets).
    Format {
        adapter: String,
        format: wgpu::TextureFormat,
    },
}

impl fmt::Display for GpuError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            GpuError::NoAdapter { backends } => write!(
                f,
                "no graphics adapter found (backends tried: {}). Install a Vulkan driver \
                 (on Debian/Ubuntu: `apt-get install mesa-vulkan-drivers libvulkan1` gives the \
                 software driver lavapipe), or pick other backends with --backend or WGPU_BACKEND",
                backend_names(*backends)
            ),
            GpuError::Device(e) => write!(f, "the graphics adapter refused the device: {e}"),
            GpuError::Format { adapter, format } => write!(
                f,
                "the graphics adapter {adapter} cannot render to {format:?} textures, which the \
                 renderer draws into. Use a Vulkan driver (`--backend vulkan`; on Debian/Ubuntu \
                 `apt-get install mesa-vulkan-drivers libvulkan1` gives the software driver \
                 lavapipe)"
            ),
        }
    }
}

impl std::error::Error for GpuError {}

/// "vulkan,gl" for a set of backends.
pub fn backend_names(b: Backends) -> String {
    let names: Vec<&str> = [
        (Backends::VULKAN, "vulkan"),
        (Backends::GL, "gl"),
        (Backends::METAL, "metal"),
        (Backends::DX12, "dx12"),
        (Backends::BROWSER_WEBGPU, "webgpu"),
    ]
    .into_iter()
    .filter(|(flag, _)| b.contains(*flag))
    .map(|(_, n)| n)
    .collect();
    if names.is_empty() {
        "none".into()
    } else {
        names.join(",")
    }
}

/// Parses `--backend` (wgpu's names: vulkan, gl, metal, dx12, comma-separated) or "all".
pub fn parse_backends(s: &str) -> Result<Backends, String> {
    if s.eq_ignore_ascii_case("all") || s.eq_ignore_ascii_case("primary") {
        return Ok(Backends::PRIMARY | Backends::GL);
    }
    let mut b = Backends::empty();
    for name in s.split(',') {
        b |= match name.trim().to_ascii_lowercase().as_str() {
            "vulkan" | "vk" => Backends::VULKAN,
            "gl" | "gles" | "opengl" => Backends::GL,
            "metal" | "mtl" => Backends::METAL,
            "dx12" | "d3d12" => Backends::DX12,
            other => {
                return Err(format!(
                    "unknown backend {other:?} (vulkan, gl, metal, dx12, all)"
                ));
            }
        };
    }
    Ok(b)
}

/// The device and what the renderer learned about it.
pub struct Gpu {
    pub instance: wgpu::Instance,
    pub adapter: wgpu::Adapter,
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    /// Largest shadow-map array the device allows (layers).
    pub max_layers: u32,
}

/// "llvmpipe (LLVM 15.0.6, 256 bits) on Vulkan".
fn describe_adapter(adapter: &wgpu::Adapter) -> String {
    let info = adapter.get_info();
    format!("{} on {:?}", info.name, info.backend)
}

/// The device features the render targets need: none where WebGPU's guarantees cover them, else
/// the adapter's own format capabilities; or, where the adapter cannot render to one of them, why.
fn render_target_features(
    adapter: &wgpu::Adapter,
    targets: &[wgpu::TextureFormat],
) -> Result<wgpu::Features, GpuError> {
    let renders = |features: wgpu::TextureFormatFeatures| {
        features
            .allowed_usages
            .contains(wgpu::TextureUsages::RENDER_ATTACHMENT)
    };
    let offered = adapter.features();
    let specific = offered.contains(wgpu::Features::TEXTURE_ADAPTER_SPECIFIC_FORMAT_FEATURES);
    let mut needed = wgpu::Features::empty();
    for &format in targets {
        // The adapter's own capabilities are what its device validates against: a GL driver
        // may lack a format that WebGPU guarantees (32-bit float colour without
        // EXT_color_buffer_float).
        let guaranteed = renders(format.guaranteed_format_features(offered));
        if !renders(adapter.get_texture_format_features(format)) || !(guaranteed || specific) {
            return Err(GpuError::Format {
                adapter: describe_adapter(adapter),
                format,
            });
        }
        if !guaranteed {
            needed |= wgpu::Features::TEXTURE_ADAPTER_SPECIFIC_FORMAT_FEATURES;
        }
    }
    Ok(needed)
}

impl Gpu {
    /// The backends to try: `--backend` if given, else `WGPU_BACKEND`, else Vulkan then GL.
    pub fn backends(choice: Option<Backends>) -> Backends {
        choice
            .or_else(Backends::from_env)
            .unwrap_or(Backends::VULKAN | Backends::GL | Backends::METAL | Backends::DX12)
    }

    /// A headless device that can render to every format of `targets` (the renderer's are
    /// [`crate::render::TARGET_FORMATS`]).
    pub fn new(backends: Backends, targets: &[wgpu::TextureFormat]) -> Result<Gpu, GpuError> {
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor {
            backends,
            ..wgpu::InstanceDescriptor::new_without_display_handle()
        });
        Self::with_instance(instance, backends, None, targets)
    }

    /// A device for an instance, compatible with `surface` when one is given, that can render
    /// to every format of `targets`.
    pub fn with_instance(
        instance: wgpu::Instance,
        backends: Backends,
        surface: Option<&wgpu::Surface<'_>>,
        targets: &[wgpu::TextureFormat],
    ) -> Result<Gpu, GpuError> {
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: surface,
            apply_limit_buckets: false,
        }))
        .map_err(|_| GpuError::NoAdapter { backends })?;
        let required_features = render_target_features(&adapter, targets)?;
        // Ask for everything the adapter offers: the defaults allow only 256 array layers, and the
        // shadow array wants one per light (up to 1 024 in the convergence test).
        let available = adapter.limits();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("vemlight"),
            required_features,
            required_limits: available.clone(),
            ..Default::default()
        }))
        .map_err(|e| GpuError::Device(e.to_string()))?;
        Ok(Gpu {
            instance,
            max_layers: available.max_texture_array_layers,
            adapter,
            device,
            queue,
        })
    }

    /// "llvmpipe (LLVM 15.0.6, 256 bits) on Vulkan".
    pub fn describe(&self) -> String {
        describe_adapter(&self.adapter)
    }

    /// Whether this adapter is the GL backend, where the shadow array pads its layer count
    /// (STACK.md).
    pub fn is_gl(&self) -> bool {
        self.adapter.get_info().backend == wgpu::Backend::Gl
    }
}
