//! The `vemlight` command line: one argument struct per command (clap derive), the flags the
//! commands share, and each command's run function. `main.rs` only parses and maps the result to
//! an exit code.

pub mod bench;
pub mod eval;
pub mod healthcheck;
pub mod lights;
pub mod serve;

use crate::envmap::Projection;
use crate::lights::Method;
use crate::mapping::Domain;
use anyhow::bail;
use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "vemlight",
    version,
    about = "Directional lights from HDR environment maps"
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand)]
pub enum Command {
    /// One environment map (OpenEXR or Radiance HDR) → a LightSet on stdout.
    Lights(lights::LightsArgs),
    /// The capture daemon: frames → filtered lights → WebSocket stream and HTTP endpoints.
    Serve(Box<serve::ServeArgs>),
    /// Exits 0 when a daemon answers `GET /healthz` with 200 (for container health checks).
    Healthcheck(healthcheck::HealthcheckArgs),
    /// Per-frame extraction speed of every method (single thread, decoding excluded), as medians
    /// and ratios to median cut measured in the same run.
    Bench(bench::BenchArgs),
    /// Accuracy × speed charts, temporal stability and the hard-case table of every method
    /// (writes docs/eval/ and the generated sections of docs/EVALUATION.md).
    Eval(eval::EvalArgs),
    /// The render client: a scene lit by the lights of a stream, a LightSet file or a map, with
    /// shadows; windowed, headless (PNG frames) or --bench (docs/RENDER.md).
    #[cfg(feature = "render")]
    View(crate::render::view::ViewArgs),
}

/// Runs the command `cli` names.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Lights(args) => lights::run(args),
        Command::Bench(args) => bench::run(args),
        Command::Eval(args) => eval::run(args),
        Command::Serve(args) => serve::run(*args),
        Command::Healthcheck(args) => healthcheck::run(&args.addr),
        #[cfg(feature = "render")]
        Command::View(args) => crate::render::view::run(args),
    }
}

/// The extraction flags `lights` and `serve` share: how lights are placed and where from.
#[derive(clap::Args, Clone, Copy, Debug)]
pub struct ExtractionArgs {
    /// How lights are computed from a map (k-means, which iterates to convergence, is for single
    /// maps only).
    #[arg(long, value_enum, default_value_t = Method::Voronoi)]
    pub method: Method,
    /// Directions lights may come from. Default: sphere for lat-long input, upper otherwise.
    #[arg(long, value_enum)]
    pub domain: Option<Domain>,
    /// Extra Lloyd steps of the voronoi method (more accurate, one assignment pass each).
    #[arg(long, default_value_t = vemlight_default_refine(), value_parser = clap::value_parser!(u8).range(0..=8))]
    pub refine: u8,
}

/// [`crate::lights::DEFAULT_REFINE`] as the `u8` `--refine` takes.
const fn vemlight_default_refine() -> u8 {
    crate::lights::DEFAULT_REFINE as u8
}

/// How the input's pixels map to directions.
#[derive(clap::Args)]
pub struct ProjectionArgs {
    /// latlong, fisheye-equidistant, fisheye-equisolid or hemisphere-square.
    /// Default: latlong for 2:1 images, fisheye-equidistant otherwise.
    #[arg(long, value_parser = Projection::parse)]
    pub projection: Option<Projection>,
    /// Fisheye field of view in degrees.
    #[arg(long, value_name = "DEG")]
    pub fov: Option<f64>,
    /// Fisheye image circle: centre and radius in pixels.
    #[arg(long, value_name = "CX,CY,R", value_parser = parse_circle)]
    pub circle: Option<(f64, f64, f64)>,
}

pub fn parse_circle(s: &str) -> Result<(f64, f64, f64), String> {
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

impl ProjectionArgs {
    /// The projection asked for, with --fov and --circle applied to a fisheye (and refused for
    /// any other projection).
    pub fn resolve(&self) -> anyhow::Result<Option<Projection>> {
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
