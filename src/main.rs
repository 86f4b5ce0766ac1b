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
#[command(name = "vemlight", version, about = "Directional lights from HDR environment maps")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// One environment map (OpenEXR or Radiance HDR) → a LightSet on stdout.
    Lights(LightsArgs),
    /// The render client: a scene lit by the lights of a stream, a LightSet file or a map, with
    /// shadows; windowed, headless (PNG frames) or --bench (docs/RENDER.md).
    #[cfg(feature = "render")]
    View(vemlight::render::view::ViewArgs),
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
    /// voronoi (default), paper, or median-cut.
    #[arg(long, default_value = "voronoi")]
    method: Method,
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
    /// Output format.
    #[arg(long, value_enum, default_value_t = Format::Json)]
    format: Format,
    /// Refuse images with more pixels than this.
    #[arg(long, default_value_t = DEFAULT_MAX_PIXELS)]
    max_pixels: u64,
    /// Leave out the L2 spherical harmonics.
    #[arg(long)]
    no_sh: bool,
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
    let projection = fisheye_overrides(args.projection, args.fov, args.circle)?;
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
    let mut set = lightset_for_map(&mut Extractor::new(), &map, &req, &source);
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

/// Applies --fov and --circle to a fisheye projection (and refuses them for any other).
fn fisheye_overrides(
    projection: Option<Projection>,
    fov: Option<f64>,
    circle: Option<(f64, f64, f64)>,
) -> anyhow::Result<Option<Projection>> {
    if fov.is_none() && circle.is_none() {
        return Ok(projection);
    }
    let base = projection.unwrap_or(Projection::parse("fisheye").expect("known"));
    match base {
        Projection::Fisheye {
            lens,
            fov_deg,
            centre,
            radius,
        } => Ok(Some(Projection::Fisheye {
            lens,
            fov_deg: fov.unwrap_or(fov_deg),
            centre: circle.map(|c| (c.0, c.1)).or(centre),
            radius: circle.map(|c| c.2).or(radius),
        })),
        other => bail!("--fov and --circle apply to fisheye projections, not {}", other.name()),
    }
}
