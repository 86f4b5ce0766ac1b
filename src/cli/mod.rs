//! The `vemlight` command line: one argument struct per command (clap derive), the flags the
//! commands share, and each command's run function. `main.rs` only parses and maps the result to
//! an exit code.

mod args;
pub mod bench;
pub mod cameras;
pub mod eval;
pub mod healthcheck;
pub mod lights;
pub mod serve;

pub use args::{ExtractionArgs, ProjectionArgs, parse_circle};

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
    /// The cameras publishing on a NATS broker (`serve --publish`): name, health, light counts.
    Cameras(cameras::CamerasArgs),
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
        Command::Cameras(args) => cameras::run(&args),
        Command::Healthcheck(args) => healthcheck::run(&args.addr),
        #[cfg(feature = "render")]
        Command::View(args) => crate::render::view::run(args),
    }
}
