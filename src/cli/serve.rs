//! `vemlight serve`: the capture daemon — a frame source, the pipeline threads and the HTTP /
//! WebSocket server, until SIGINT or SIGTERM.
// The flags' doc comments are their `--help` text, written for a terminal (a URL, `<camera>`).
#![allow(rustdoc::bare_urls, rustdoc::invalid_html_tags)]

use super::args::{ExtractionArgs, ProjectionArgs};
use crate::envmap::{DEFAULT_MAX_PIXELS, Projection};
use crate::lights::Method;
use anyhow::{Context, bail};

/// Where the daemon listens unless `--bind` or `VEMLIGHT_BIND` says otherwise.
pub const DEFAULT_BIND: &str = "127.0.0.1:7878";

/// The frame rates `--fps` may name: one frame in 1000 s up to 1000 frames/s.
const MIN_FPS: f64 = 0.001;
const MAX_FPS: f64 = 1000.0;

#[derive(clap::Args)]
pub struct ServeArgs {
    /// Address to listen on.
    #[arg(long, env = "VEMLIGHT_BIND", default_value = DEFAULT_BIND)]
    pub bind: String,
    /// Where frames come from: `synthetic` (a built-in dynamic sky), `stdin` (raw frames, also
    /// `-`), or the path of an .exr/.hdr file (re-emitted at --fps) or of a directory of frames
    /// (played in name order at --fps).
    #[arg(long, default_value = "synthetic", value_name = "synthetic|stdin|PATH")]
    pub source: SourceArg,
    /// Frame rate of the synthetic, file and directory sources; for stdin, the rate the producer
    /// is expected to write at (frames are read as they come; it states the filter's delay and
    /// cut-off in time and when a silent producer counts as stalled).
    #[arg(long, default_value_t = 30.0)]
    pub fps: f64,
    /// Loop a directory source.
    #[arg(long = "loop")]
    pub looping: bool,
    /// Raw frame width (stdin source).
    #[arg(long)]
    pub width: Option<usize>,
    /// Raw frame height (stdin source).
    #[arg(long)]
    pub height: Option<usize>,
    /// Raw pixel layout (stdin source).
    #[arg(long, default_value = "rgbf32le")]
    pub pixel: crate::capture::stdin::RawPixel,
    /// Projection of file, directory and stdin frames.
    #[command(flatten)]
    pub projection: ProjectionArgs,
    #[command(flatten)]
    pub extraction: ExtractionArgs,
    /// Light count published when no client asks for another (clients pick theirs with ?lights=N).
    #[arg(long, default_value_t = 64)]
    pub lights: usize,
    /// Temporal filter per light id.
    #[arg(long, default_value = "binomial")]
    pub filter: crate::temporal::FilterKind,
    /// Filter taps (group delay = (taps − 1)/2 frames).
    #[arg(long, default_value_t = 9)]
    pub taps: usize,
    /// Cut-off of the sinc filter in Hz at --fps.
    #[arg(long, default_value_t = 3.0)]
    pub cutoff_hz: f64,
    /// Bearer token required by every endpoint but /healthz.
    #[arg(long, env = "VEMLIGHT_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    /// A web page origin allowed to call the API from a browser (CORS), e.g.
    /// https://app.example.com; repeat for more, or `*` for any. None by default.
    #[arg(long = "cors-origin", value_name = "ORIGIN")]
    pub cors_origins: Vec<String>,
    /// Largest accepted POST body in bytes.
    #[arg(long, default_value_t = 64 * 1024 * 1024)]
    pub max_body: usize,
    /// Largest accepted image (uploads and frames) in pixels.
    #[arg(long, default_value_t = DEFAULT_MAX_PIXELS)]
    pub max_pixels: u64,
    /// Concurrent POST extractions (default: the number of cores).
    #[arg(long)]
    pub post_workers: Option<usize>,
    /// Most WebSocket clients of /v1/stream at once; one more is answered 503 (default: the
    /// descriptor limit, `ulimit -n`, less 320: 704 for 1024; docs/API.md "Limits").
    #[arg(long, env = "VEMLIGHT_MAX_CLIENTS")]
    pub max_clients: Option<usize>,
    /// Most connections open at once, WebSocket clients included; at the cap new connections wait
    /// in the listen backlog (default: --max-clients + 64, or the descriptor limit less 256).
    #[arg(long, env = "VEMLIGHT_MAX_CONNECTIONS")]
    pub max_connections: Option<usize>,
    /// Synthetic sky size, WxH (lat-long, 2:1).
    #[arg(long, default_value = "1024x512", value_parser = parse_size)]
    pub sky_size: (usize, usize),
    /// Synthetic sun speed along its day path, degrees per second (negative: backwards).
    #[arg(long, default_value_t = 1.0, allow_negative_numbers = true)]
    pub sun_speed: f64,
    /// Synthetic cloud cover, 0–1.
    #[arg(long, default_value_t = 0.3, allow_negative_numbers = true)]
    pub clouds: f64,
    /// Period of the synthetic lamp that switches on and off, seconds (0: no lamp).
    #[arg(long, default_value_t = 10.0)]
    pub switch_period: f64,
    #[command(flatten)]
    pub publish: PublishArgs,
}

/// Publishing through a NATS broker (docs/API.md, "Through a NATS broker").
#[derive(clap::Args)]
pub struct PublishArgs {
    /// Also publish every LightSet to this NATS broker (nats://HOST:PORT), for many viewers and
    /// many cameras. Credentials never go here: VEMLIGHT_NATS_TOKEN, VEMLIGHT_NATS_USER and
    /// VEMLIGHT_NATS_PASSWORD, --nats-token-file or --nats-creds (or the whole URL in
    /// VEMLIGHT_NATS).
    #[arg(
        long,
        env = "VEMLIGHT_NATS",
        hide_env_values = true,
        value_name = "URL"
    )]
    pub publish: Option<String>,
    /// This camera's name on the broker, a subject token (default: the host name, sanitised).
    #[arg(long, env = "VEMLIGHT_CAMERA")]
    pub camera: Option<String>,
    /// Light counts published to the broker, each on vemlight.v1.<camera>.lights.<n> (default:
    /// --lights).
    #[arg(long, value_delimiter = ',', value_name = "N,N,…")]
    pub publish_lights: Vec<usize>,
    /// How to log in to the broker.
    #[command(flatten)]
    pub login: crate::publish::login::LoginArgs,
    /// Replicas of the camera's JetStream last-value stream: 1 on a single broker, 3 on a
    /// cluster (docs/SCALING.md). The daemon sets it on every connection.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..=5))]
    pub nats_replicas: u8,
}

/// Most light counts published to a broker: each takes one of the hub's
/// [`MAX_LIGHT_COUNTS`](crate::daemon::MAX_LIGHT_COUNTS) streams, and clients need the rest.
pub const MAX_PUBLISHED_COUNTS: usize = 8;

impl PublishArgs {
    /// The publisher's configuration, when --publish is given; credentials from the environment
    /// or files.
    fn config(
        &self,
        default_lights: usize,
    ) -> anyhow::Result<Option<crate::publish::PublishConfig>> {
        use crate::publish::{PublishConfig, check_url, subjects};
        let Some(url) = self.publish.clone() else {
            return Ok(None);
        };
        let from_env = std::env::var("VEMLIGHT_NATS").is_ok_and(|v| v == url);
        check_url(&url, from_env).map_err(anyhow::Error::msg)?;
        let camera = match &self.camera {
            Some(c) => {
                subjects::check_camera(c).map_err(|e| anyhow::anyhow!("--camera: {e}"))?;
                c.clone()
            }
            None => subjects::default_camera(),
        };
        let mut counts = if self.publish_lights.is_empty() {
            vec![default_lights]
        } else {
            self.publish_lights.clone()
        };
        counts.sort_unstable();
        counts.dedup();
        if let Some(&n) = counts
            .iter()
            .find(|&&n| !(1..=crate::sampling::N_MAX).contains(&n))
        {
            bail!(
                "--publish-lights: {n} is not a light count between 1 and {}",
                crate::sampling::N_MAX
            );
        }
        if counts.len() > MAX_PUBLISHED_COUNTS {
            bail!(
                "--publish-lights names {} counts; at most {MAX_PUBLISHED_COUNTS} (each costs an assignment pass a frame)",
                counts.len()
            );
        }
        let auth = self.login.auth()?;
        Ok(Some(PublishConfig {
            url,
            camera,
            counts,
            auth,
            http: None,
            replicas: self.nats_replicas as usize,
        }))
    }
}

pub fn parse_size(s: &str) -> Result<(usize, usize), String> {
    let (w, h) = s
        .split_once('x')
        .ok_or_else(|| format!("expected WxH, got '{s}'"))?;
    let w = w.trim().parse().map_err(|e| format!("width: {e}"))?;
    let h = h.trim().parse().map_err(|e| format!("height: {e}"))?;
    Ok((w, h))
}

/// `vemlight serve`: builds the source, starts the pipeline threads and serves until SIGINT or
/// SIGTERM.
pub fn run(args: ServeArgs) -> anyhow::Result<()> {
    use crate::daemon::{self, Hub, PipelineConfig};
    use crate::server::{AppState, CorsOrigins, Limits, Uploads, WsConfig, run, shutdown_signal};
    use crate::temporal::{FilterKind, FilterSpec};

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
    if !(1..=crate::sampling::N_MAX).contains(&args.lights) {
        bail!("--lights must be between 1 and {}", crate::sampling::N_MAX);
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
        Method::STREAMING.contains(&args.extraction.method),
        "--method {} is a baseline for single maps (it iterates to convergence, up to seconds a frame); a stream takes {}",
        args.extraction.method.name(),
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
    let publish = args.publish.config(args.lights)?;
    let limits =
        Limits::resolve(args.max_clients, args.max_connections).map_err(anyhow::Error::msg)?;

    let hub = Hub::new(args.lights, daemon::MAX_LIGHT_COUNTS, &source.describe());
    let cfg = PipelineConfig {
        method: args.extraction.method,
        domain: args.extraction.domain,
        filter,
        sh9: true,
        refine: args.extraction.refine as usize,
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
    .with_cors(cors)
    .with_limits(limits);
    let runtime = tokio::runtime::Runtime::new()?;
    runtime.block_on(async move {
        let listener = tokio::net::TcpListener::bind(addr)
            .await
            .with_context(|| format!("cannot listen on {addr}"))?;
        let addr = listener.local_addr()?;
        let state = match publish {
            Some(p) => {
                let p = crate::publish::PublishConfig {
                    http: Some(format!("http://{addr}")),
                    ..p
                };
                state.with_broker(crate::publish::start(p, hub.clone()).await?)
            }
            None => state,
        };
        daemon::spawn(source, hub.clone(), cfg)?;
        tracing::info!(
            "vemlight serving on http://{addr} (stream: ws://{addr}/v1/stream){}",
            if state.token.is_some() {
                ", token required"
            } else {
                ""
            }
        );
        tracing::info!(
            "at most {} WebSocket clients and {} connections at once",
            state.limits.max_ws_clients(),
            state.limits.max_connections()
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
    crate::envmap::check_pixel_limit(width as u64, height as u64, args.max_pixels)
        .map_err(|_| anyhow::anyhow!("{what} is over --max-pixels ({})", args.max_pixels))
}

/// What `--source` names.
#[derive(Clone, Debug, PartialEq)]
pub enum SourceArg {
    /// The built-in dynamic sky ([`crate::sky`]): the daemon runs with no camera and no data.
    Synthetic,
    /// Raw frames on standard input.
    Stdin,
    /// An .exr/.hdr file or a directory of frames.
    Path(std::path::PathBuf),
}

impl std::str::FromStr for SourceArg {
    type Err = std::convert::Infallible;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Ok(match s {
            "synthetic" => SourceArg::Synthetic,
            "stdin" | "-" => SourceArg::Stdin,
            path => SourceArg::Path(path.into()),
        })
    }
}

/// The frame source `--source` names.
fn make_source(
    args: &ServeArgs,
    projection: Option<Projection>,
) -> anyhow::Result<Box<dyn crate::capture::FrameSource>> {
    use crate::capture::files::{DirectorySource, FileSource};
    use crate::capture::stdin::RawSource;
    use crate::capture::synthetic::SyntheticSource;
    use crate::sky::{SwitchLight, SyntheticConfig};
    Ok(match &args.source {
        SourceArg::Synthetic => {
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
            if args.switch_period < 0.0 {
                bail!(
                    "--switch-period must be at least 0 (0: no lamp), got {}",
                    args.switch_period
                );
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
        SourceArg::Stdin => {
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
        SourceArg::Path(path) => {
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
