//! `vemlight lights FILE`: one map → one LightSet (or glTF) on stdout.

use super::args::{ExtractionArgs, ProjectionArgs};
use crate::envmap::{DEFAULT_MAX_PIXELS, EnvMap};
use crate::lights::Extractor;
use crate::lightset::{LightRequest, lightset_for_map, to_gltf};
use anyhow::Context;
use clap::ValueEnum;
use std::io::Write;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct LightsArgs {
    /// The map: .exr or .hdr (format sniffed from the content).
    pub file: PathBuf,
    /// Number of lights (1–1024); with --max-error, the most allowed.
    #[arg(long, short = 'n', default_value_t = 64)]
    pub lights: usize,
    /// Pick the fewest lights (at most --lights) whose estimated relative diffuse irradiance
    /// error is ≤ E; `diagnostics.lights_chosen` says how many.
    #[arg(long, value_name = "E")]
    pub max_error: Option<f64>,
    #[command(flatten)]
    pub projection: ProjectionArgs,
    #[command(flatten)]
    pub extraction: ExtractionArgs,
    /// Output format.
    #[arg(long, value_enum, default_value_t = Format::Json)]
    pub format: Format,
    /// Refuse images with more pixels than this.
    #[arg(long, default_value_t = DEFAULT_MAX_PIXELS)]
    pub max_pixels: u64,
    /// Leave out the L2 spherical harmonics.
    #[arg(long)]
    pub no_sh: bool,
}

#[derive(Clone, Copy, ValueEnum)]
pub enum Format {
    /// The LightSet document (proto/lightset.schema.json).
    Json,
    /// glTF 2.0 with KHR_lights_punctual directional lights.
    Gltf,
}

/// `vemlight lights FILE`.
pub fn run(args: LightsArgs) -> anyhow::Result<()> {
    let projection = args.projection.resolve()?;
    let req = LightRequest {
        lights: args.lights,
        domain: args.extraction.domain,
        method: args.extraction.method,
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
    extractor.set_refine(args.extraction.refine as usize);
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
