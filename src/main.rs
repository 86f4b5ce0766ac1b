//! The `vemlight` command line: parse, dispatch, one exit-code policy.

use anyhow::{Context, bail};
use clap::{Parser, Subcommand, ValueEnum};
use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;
use vemlight::envmap::{DEFAULT_MAX_PIXELS, EnvMap, Projection};
use vemlight::lights::{Extractor, Method};
use vemlight::lightset::{LightRequest, lightset_for_map, to_gltf};
use vemlight::sampling::Domain;

#[derive(Parser)]
#[command(
    name = "vemlight",
    version,
    about = "Directional lights from HDR environment maps"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// One environment map (OpenEXR or Radiance HDR) → a LightSet on stdout.
    Lights(LightsArgs),
    /// The capture daemon: frames → filtered lights → WebSocket stream and HTTP endpoints.
    Serve(Box<ServeArgs>),
    /// Exits 0 when a daemon answers `GET /healthz` with 200 (for container health checks).
    Healthcheck {
        /// host:port of the daemon, read as `serve --bind` reads it (an any-interface address
        /// is asked on loopback).
        #[arg(env = "VEMLIGHT_BIND", default_value = DEFAULT_BIND)]
        addr: String,
    },
    /// Per-frame extraction speed of every method (single thread, decoding excluded), as medians
    /// and ratios to median cut measured in the same run.
    Bench(BenchArgs),
    /// Accuracy × speed charts, temporal stability and the hard-case table of every method
    /// (writes docs/eval/ and the generated sections of docs/EVALUATION.md).
    Eval(EvalArgs),
    /// The render client: a scene lit by the lights of a stream, a LightSet file or a map, with
    /// shadows; windowed, headless (PNG frames) or --bench (docs/RENDER.md).
    #[cfg(feature = "render")]
    View(vemlight::render::view::ViewArgs),
}

#[derive(clap::Args)]
struct EvalArgs {
    /// Directory of lat-long .exr/.hdr maps.
    #[arg(long, default_value = "tests/data")]
    maps: PathBuf,
    /// Output directory for CSV, SVG and markdown tables.
    #[arg(long, default_value = "docs/eval")]
    out: PathBuf,
    /// Document whose generated sections (<!-- BEGIN name --> … <!-- END name -->) are rewritten;
    /// skipped when it does not exist.
    #[arg(long, default_value = "docs/EVALUATION.md")]
    doc: PathBuf,
    /// Fewer light counts, one timing run, 16 frames per sequence: a smoke run.
    #[arg(long)]
    quick: bool,
    /// Also evaluate lights restricted to the upper hemisphere.
    #[arg(long)]
    upper: bool,
}

#[derive(clap::Args)]
struct ServeArgs {
    /// Address to listen on.
    #[arg(long, env = "VEMLIGHT_BIND", default_value = DEFAULT_BIND)]
    bind: String,
    /// `synthetic` (a built-in dynamic sky), `stdin` (raw frames), an .exr/.hdr file (re-emitted
    /// at --fps) or a directory of frames (played in name order at --fps).
    #[arg(long, default_value = "synthetic")]
    source: String,
    /// Frame rate of the synthetic, file and directory sources; for stdin, the rate the producer
    /// is expected to write at (frames are read as they come; it states the filter's delay and
    /// cut-off in time and when a silent producer counts as stalled).
    #[arg(long, default_value_t = 30.0)]
    fps: f64,
    /// Loop a directory source.
    #[arg(long = "loop")]
    looping: bool,
    /// Raw frame width (stdin source).
    #[arg(long)]
    width: Option<usize>,
    /// Raw frame height (stdin source).
    #[arg(long)]
    height: Option<usize>,
    /// Raw pixel layout (stdin source): rgbf32le, rgbf16le or rgb48le.
    #[arg(long, default_value = "rgbf32le")]
    pixel: vemlight::capture::stdin::RawPixel,
    /// Projection of file, directory and stdin frames.
    #[command(flatten)]
    projection: ProjectionArgs,
    /// Light count published when no client asks for another (clients pick theirs with ?lights=N).
    #[arg(long, default_value_t = 64)]
    lights: usize,
    /// voronoi (default), paper, median-cut, inverse-cdf or vmlps (k-means, which iterates to
    /// convergence, is for single maps only).
    #[arg(long, default_value = "voronoi")]
    method: Method,
    /// Default: sphere for lat-long sources, upper for fisheye sources.
    #[arg(long)]
    domain: Option<Domain>,
    /// Extra Lloyd steps of the voronoi method (more accurate, one assignment pass each).
    #[arg(long, default_value_t = vemlight::lights::DEFAULT_REFINE as u8, value_parser = clap::value_parser!(u8).range(0..=8))]
    refine: u8,
    /// Temporal filter per light id: binomial (default), sinc or none.
    #[arg(long, default_value = "binomial")]
    filter: vemlight::temporal::FilterKind,
    /// Filter taps (group delay = (taps − 1)/2 frames).
    #[arg(long, default_value_t = 9)]
    taps: usize,
    /// Cut-off of the sinc filter in Hz at --fps.
    #[arg(long, default_value_t = 3.0)]
    cutoff_hz: f64,
    /// Bearer token required by every endpoint but /healthz.
    #[arg(long, env = "VEMLIGHT_TOKEN", hide_env_values = true)]
    token: Option<String>,
    /// A web page origin allowed to call the API from a browser (CORS), e.g.
    /// https://app.example.com; repeat for more, or `*` for any. None by default.
    #[arg(long = "cors-origin", value_name = "ORIGIN")]
    cors_origins: Vec<String>,
    /// Largest accepted POST body in bytes.
    #[arg(long, default_value_t = 64 * 1024 * 1024)]
    max_body: usize,
    /// Largest accepted image (uploads and frames) in pixels.
    #[arg(long, default_value_t = DEFAULT_MAX_PIXELS)]
    max_pixels: u64,
    /// Concurrent POST extractions (default: the number of cores).
    #[arg(long)]
    post_workers: Option<usize>,
    /// Synthetic sky size, WxH (lat-long, 2:1).
    #[arg(long, default_value = "1024x512", value_parser = parse_size)]
    sky_size: (usize, usize),
    /// Synthetic sun speed along its day path, degrees per second (negative: backwards).
    #[arg(long, default_value_t = 1.0, allow_negative_numbers = true)]
    sun_speed: f64,
    /// Synthetic cloud cover, 0–1.
    #[arg(long, default_value_t = 0.3, allow_negative_numbers = true)]
    clouds: f64,
    /// Period of the synthetic lamp that switches on and off, seconds (0: no lamp).
    #[arg(long, default_value_t = 10.0)]
    switch_period: f64,
}

fn parse_size(s: &str) -> Result<(usize, usize), String> {
    let (w, h) = s
        .split_once('x')
        .ok_or_else(|| format!("expected WxH, got '{s}'"))?;
    let w = w.trim().parse().map_err(|e| format!("width: {e}"))?;
    let h = h.trim().parse().map_err(|e| format!("height: {e}"))?;
    Ok((w, h))
}

#[derive(clap::Args)]
struct BenchArgs {
    /// A lat-long map; the fisheye case sees it through a 180° equidistant lens.
    #[arg(long, default_value = "tests/data/sunrise.exr")]
    map: PathBuf,
    #[arg(long, default_value_t = 256)]
    lights: usize,
    /// Interleaved rounds; each times every case `--per-round` times.
    #[arg(long, default_value_t = 15)]
    rounds: usize,
    #[arg(long, default_value_t = 20)]
    per_round: usize,
}

#[derive(clap::Args)]
struct LightsArgs {
    /// The map: .exr or .hdr (format sniffed from the content).
    file: PathBuf,
    /// Number of lights (1–1024); with --max-error, the most allowed.
    #[arg(long, short = 'n', default_value_t = 64)]
    lights: usize,
    /// Pick the smallest power-of-two light count whose relative diffuse irradiance error is ≤ E.
    #[arg(long, value_name = "E")]
    max_error: Option<f64>,
    /// Directions lights may come from: `upper` (hemisphere) or `sphere`.
    /// Default: sphere for lat-long input, upper otherwise.
    #[arg(long)]
    domain: Option<Domain>,
    /// voronoi (default), paper, median-cut, inverse-cdf, vmlps or k-means (the diffuse floor; slow).
    #[arg(long, default_value = "voronoi")]
    method: Method,
    #[command(flatten)]
    projection: ProjectionArgs,
    /// Output format.
    #[arg(long, value_enum, default_value_t = Format::Json)]
    format: Format,
    /// Refuse images with more pixels than this.
    #[arg(long, default_value_t = DEFAULT_MAX_PIXELS)]
    max_pixels: u64,
    /// Leave out the L2 spherical harmonics.
    #[arg(long)]
    no_sh: bool,
    /// Extra Lloyd steps of the voronoi method (more accurate, one assignment pass each).
    #[arg(long, default_value_t = vemlight::lights::DEFAULT_REFINE as u8, value_parser = clap::value_parser!(u8).range(0..=8))]
    refine: u8,
}

/// How the input's pixels map to directions.
#[derive(clap::Args)]
struct ProjectionArgs {
    /// latlong, fisheye-equidistant, fisheye-equisolid or hemisphere-square.
    /// Default: latlong for 2:1 images, fisheye-equidistant otherwise.
    #[arg(long, value_parser = Projection::parse)]
    projection: Option<Projection>,
    /// Fisheye field of view in degrees.
    #[arg(long, value_name = "DEG")]
    fov: Option<f64>,
    /// Fisheye image circle: centre and radius in pixels.
    #[arg(long, value_name = "CX,CY,R", value_parser = parse_circle)]
    circle: Option<(f64, f64, f64)>,
}

#[derive(Clone, Copy, ValueEnum)]
enum Format {
    /// The LightSet document (proto/lightset.schema.json).
    Json,
    /// glTF 2.0 with KHR_lights_punctual directional lights.
    Gltf,
}

fn parse_circle(s: &str) -> Result<(f64, f64, f64), String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|p| p.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|e| format!("expected CX,CY,R: {e}"))?;
    match v[..] {
        [cx, cy, r] => Ok((cx, cy, r)),
        _ => Err(format!("expected three numbers CX,CY,R, got {}", v.len())),
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Lights(args) => run_lights(args),
        Command::Bench(args) => run_bench(args),
        Command::Eval(args) => run_eval(args),
        Command::Serve(args) => run_serve(*args),
        Command::Healthcheck { addr } => healthcheck(&addr),
        #[cfg(feature = "render")]
        Command::View(args) => vemlight::render::view::run(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            // A reader that closed the pipe early (`| head`) is a normal end.
            if err
                .downcast_ref::<std::io::Error>()
                .is_some_and(|e| e.kind() == std::io::ErrorKind::BrokenPipe)
            {
                return ExitCode::SUCCESS;
            }
            eprintln!("vemlight: error: {err:#}");
            ExitCode::FAILURE
        }
    }
}

/// `vemlight lights FILE`.
fn run_lights(args: LightsArgs) -> anyhow::Result<()> {
    let projection = args.projection.resolve()?;
    let req = LightRequest {
        lights: args.lights,
        domain: args.domain,
        method: args.method,
        max_error: args.max_error,
        estimate_error: true,
        sh9: !args.no_sh,
    };
    req.validate().map_err(anyhow::Error::msg)?;
    let t = std::time::Instant::now();
    let map = EnvMap::open(&args.file, projection, args.max_pixels)?;
    let decode_ms = t.elapsed().as_secs_f64() * 1e3;
    let source = args
        .file
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let mut extractor = Extractor::new();
    extractor.set_refine(args.refine as usize);
    let mut set = lightset_for_map(&mut extractor, &map, &req, &source);
    set.diagnostics.timings_ms.decode = decode_ms;
    set.diagnostics.timings_ms.total += decode_ms;
    let mut out = std::io::stdout().lock();
    match args.format {
        Format::Json => serde_json::to_writer_pretty(&mut out, &set),
        Format::Gltf => serde_json::to_writer_pretty(&mut out, &to_gltf(&set)),
    }
    .context("writing the output")?;
    writeln!(out)?;
    Ok(())
}

/// `vemlight serve`: builds the source, starts the pipeline threads and serves until SIGINT or
/// SIGTERM.
/// Where the daemon listens unless `--bind` or `VEMLIGHT_BIND` says otherwise.
const DEFAULT_BIND: &str = "127.0.0.1:7878";

/// The frame rates `--fps` may name: one frame in 1000 s up to 1000 frames/s.
const MIN_FPS: f64 = 0.001;
const MAX_FPS: f64 = 1000.0;

fn run_serve(args: ServeArgs) -> anyhow::Result<()> {
    use vemlight::capture::pipeline::{self, Hub, PipelineConfig};
    use vemlight::server::{AppState, CorsOrigins, Uploads, WsConfig, run, shutdown_signal};
    use vemlight::temporal::{FilterKind, FilterSpec};

    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        .init();

    if !(args.fps.is_finite() && (MIN_FPS..=MAX_FPS).contains(&args.fps)) {
        bail!(
            "--fps must be between {MIN_FPS} and {MAX_FPS}, got {}",
            args.fps
        );
    }
    if args.token.as_deref().is_some_and(|t| t.trim().is_empty()) {
        bail!(
            "--token (or VEMLIGHT_TOKEN) is set but empty: give a token, or unset it to serve \
             without one"
        );
    }
    if !(1..=vemlight::sampling::N_MAX).contains(&args.lights) {
        bail!(
            "--lights must be between 1 and {}",
            vemlight::sampling::N_MAX
        );
    }
    let filter = FilterSpec {
        kind: args.filter,
        taps: if args.filter == FilterKind::None {
            1
        } else {
            args.taps
        },
        cutoff: args.cutoff_hz / args.fps,
    };
    filter.validate().map_err(anyhow::Error::msg)?;
    anyhow::ensure!(
        Method::STREAMING.contains(&args.method),
        "--method {} is a baseline for single maps (it iterates to convergence, up to seconds a frame); a stream takes {}",
        args.method.name(),
        Method::STREAMING.map(|m| m.name()).join(", ")
    );
    let projection = args.projection.resolve()?;
    let source = make_source(&args, projection)?;
    let addr: std::net::SocketAddr = args.bind.parse().with_context(|| {
        format!(
            "--bind '{}' is not an address like 127.0.0.1:7878",
            args.bind
        )
    })?;

    let cors = CorsOrigins::parse(&args.cors_origins).map_err(anyhow::Error::msg)?;

    let hub = Hub::new(args.lights, 16, &source.describe());
    let cfg = PipelineConfig {
        method: args.method,
        domain: args.domain,
        default_lights: args.lights,
        filter,
        sh9: true,
        refine: args.refine as usize,
        ..PipelineConfig::default()
    };
    let workers = args
        .post_workers
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(2, |n| n.get()));
    let state = AppState::new(
        hub.clone(),
        args.token.clone(),
        Uploads::new(args.max_body, args.max_pixels, workers),
        WsConfig::default(),
    )
    .with_cors(cors);
    let runtime = tokio::runtime::Runtime::new()?;
    runtime.block_on(async move {
        let listener = tokio::net::TcpListener::bind(addr)
            .await
            .with_context(|| format!("cannot listen on {addr}"))?;
        pipeline::spawn(source, hub.clone(), cfg)?;
        let addr = listener.local_addr()?;
        tracing::info!(
            "vemlight serving on http://{addr} (stream: ws://{addr}/v1/stream){}",
            if state.token.is_some() {
                ", token required"
            } else {
                ""
            }
        );
        let hub_for_signal = hub.clone();
        run(listener, state, async move {
            shutdown_signal().await;
            tracing::info!("shutting down");
            hub_for_signal.shutdown();
        })
        .await?;
        anyhow::Ok(())
    })?;
    // The capture thread may be blocked reading stdin; it ends with the process.
    runtime.shutdown_timeout(std::time::Duration::from_secs(2));
    Ok(())
}

/// Frames of `width` × `height` (a source's size, named `what`) are within `--max-pixels`.
fn within_max_pixels(
    what: &str,
    width: usize,
    height: usize,
    args: &ServeArgs,
) -> anyhow::Result<()> {
    vemlight::envmap::check_pixel_limit(width as u64, height as u64, args.max_pixels)
        .map_err(|_| anyhow::anyhow!("{what} is over --max-pixels ({})", args.max_pixels))
}

/// The frame source `--source` names.
fn make_source(
    args: &ServeArgs,
    projection: Option<Projection>,
) -> anyhow::Result<Box<dyn vemlight::capture::FrameSource>> {
    use vemlight::capture::files::{DirectorySource, FileSource};
    use vemlight::capture::stdin::RawSource;
    use vemlight::capture::synthetic::SyntheticSource;
    use vemlight::sky::{SwitchLight, SyntheticConfig};
    Ok(match args.source.as_str() {
        "synthetic" => {
            let (width, height) = args.sky_size;
            if width != 2 * height || height < 8 {
                bail!("--sky-size must be 2:1 and at least 16x8, got {width}x{height}");
            }
            within_max_pixels(&format!("--sky-size {width}x{height}"), width, height, args)?;
            for (name, v) in [
                ("--sun-speed", args.sun_speed),
                ("--clouds", args.clouds),
                ("--switch-period", args.switch_period),
            ] {
                if !v.is_finite() {
                    bail!("{name} must be a finite number, got {v}");
                }
            }
            if !(0.0..=1.0).contains(&args.clouds) {
                bail!("--clouds must be between 0 and 1, got {}", args.clouds);
            }
            let defaults = SyntheticConfig::default();
            let cfg = SyntheticConfig {
                width,
                height,
                sun_speed_deg_per_s: args.sun_speed,
                clouds: args.clouds,
                switch_light: (args.switch_period > 0.0).then(|| SwitchLight {
                    period_s: args.switch_period,
                    ..SwitchLight::default()
                }),
                ..defaults
            };
            Box::new(SyntheticSource::new(cfg, args.fps))
        }
        "stdin" | "-" => {
            let (Some(w), Some(h)) = (args.width, args.height) else {
                bail!("--source stdin needs --width and --height");
            };
            within_max_pixels(&format!("--width × --height ({w}×{h})"), w, h, args)?;
            let projection = projection.unwrap_or_else(|| Projection::guess(w, h));
            Box::new(
                RawSource::new(std::io::stdin(), w, h, args.pixel, projection, "stdin")?
                    .with_declared_fps(args.fps),
            )
        }
        path => {
            let path = std::path::Path::new(path);
            if path.is_dir() {
                Box::new(DirectorySource::open(
                    path,
                    projection,
                    args.max_pixels,
                    args.fps,
                    args.looping,
                )?)
            } else if path.exists() {
                Box::new(FileSource::open(
                    path,
                    projection,
                    args.max_pixels,
                    args.fps,
                )?)
            } else {
                bail!(
                    "--source '{}': expected synthetic, stdin, a file or a directory",
                    path.display()
                );
            }
        }
    })
}

/// `vemlight healthcheck`: a plain HTTP/1.0 GET of /healthz.
fn healthcheck(addr: &str) -> anyhow::Result<()> {
    use std::io::Read;
    use std::net::{SocketAddr, TcpStream, ToSocketAddrs};
    let timeout = std::time::Duration::from_secs(3);
    let sock: SocketAddr = addr
        .to_socket_addrs()
        .with_context(|| format!("'{addr}' is not host:port"))?
        .next()
        .with_context(|| format!("'{addr}' names no address"))?;
    // A daemon listening on every interface is asked on loopback.
    let sock = match sock {
        SocketAddr::V4(a) if a.ip().is_unspecified() => {
            SocketAddr::from((std::net::Ipv4Addr::LOCALHOST, a.port()))
        }
        SocketAddr::V6(a) if a.ip().is_unspecified() => {
            SocketAddr::from((std::net::Ipv6Addr::LOCALHOST, a.port()))
        }
        other => other,
    };
    let mut s = TcpStream::connect_timeout(&sock, timeout)
        .with_context(|| format!("cannot connect to {sock}"))?;
    s.set_read_timeout(Some(timeout))?;
    write!(s, "GET /healthz HTTP/1.0\r\nHost: {addr}\r\n\r\n")?;
    let mut reply = String::new();
    s.read_to_string(&mut reply)?;
    let status = reply.lines().next().unwrap_or("");
    if status.split_whitespace().nth(1) == Some("200") {
        Ok(())
    } else {
        bail!("unhealthy: {status}")
    }
}

/// `vemlight eval`.
fn run_eval(args: EvalArgs) -> anyhow::Result<()> {
    let summary = vemlight::eval::run(&vemlight::eval::EvalOptions {
        maps: args.maps,
        out: args.out,
        doc: Some(args.doc),
        quick: args.quick,
        upper: args.upper,
    })?;
    println!("{summary}");
    Ok(())
}

/// `vemlight bench`.
fn run_bench(args: BenchArgs) -> anyhow::Result<()> {
    use vemlight::eval::speed;
    let bytes =
        std::fs::read(&args.map).with_context(|| format!("cannot read {}", args.map.display()))?;
    let map = EnvMap::decode(&bytes, Some(Projection::LatLong), DEFAULT_MAX_PIXELS)
        .with_context(|| args.map.display().to_string())?;
    let decode = speed::decode_median(&bytes, 21);
    println!(
        "decode {} ({}x{}): median {:.2} ms",
        args.map.display(),
        map.width,
        map.height,
        decode * 1e3
    );
    let cases = speed::standard_cases(&map, args.lights);
    println!(
        "{:<48} {:>10} {:>12} {:>9} {:>13} {:>22}",
        "case (single thread, decode excluded)",
        "median ms",
        "resample ms",
        "frames/s",
        "x median cut",
        "x median cut, bare †"
    );
    for t in speed::run(&cases, args.rounds, args.per_round) {
        let ratio = |r: Option<f64>| r.map(|r| format!("{r:.2}")).unwrap_or_default();
        println!(
            "{:<48} {:>10.3} {:>12.3} {:>9.0} {:>13} {:>22}",
            t.name,
            t.median_s * 1e3,
            t.resample_s * 1e3,
            1.0 / t.median_s,
            ratio(t.ratio_to_baseline),
            ratio(t.ratio_to_bare_baseline),
        );
    }
    println!(
        "† against median cut's time without the resampling pass, which it does not use on a lat-long source (it reads the map directly)"
    );
    Ok(())
}

impl ProjectionArgs {
    /// The projection asked for, with --fov and --circle applied to a fisheye (and refused for
    /// any other projection).
    fn resolve(&self) -> anyhow::Result<Option<Projection>> {
        if self.fov.is_none() && self.circle.is_none() {
            return Ok(self.projection);
        }
        let base = self
            .projection
            .unwrap_or(Projection::parse("fisheye").expect("known"));
        match base {
            Projection::Fisheye {
                lens,
                fov_deg,
                centre,
                radius,
            } => Ok(Some(Projection::Fisheye {
                lens,
                fov_deg: self.fov.unwrap_or(fov_deg),
                centre: self.circle.map(|c| (c.0, c.1)).or(centre),
                radius: self.circle.map(|c| c.2).or(radius),
            })),
            other => bail!(
                "--fov and --circle apply to fisheye projections, not {}",
                other.name()
            ),
        }
    }
}
