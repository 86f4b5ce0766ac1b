//! The render client app, `vemlight view`: the top of the render tree (DESIGN.md, "Processes and
//! endpoints"). It parses the arguments ([`ViewArgs`]), opens the light feed ([`source`]), keeps
//! the drawn lights within a frame budget ([`adaptive`]) and runs the frame loop in one of three
//! modes: headless PNG frames, a window, or `--bench`.
//!
//! Input: [`ViewArgs`]. Output: PNG files, a window, or the benchmark's table on stdout. Each mode
//! drives one [`Renderer`](crate::render::Renderer); nothing below this module knows about feeds,
//! arguments or modes.

pub mod adaptive;
mod args;
mod bench;
mod headless;
pub mod nats;
pub mod source;
mod window;

pub use args::{ViewArgs, camera_at};

/// Runs `vemlight view`.
pub fn run(args: ViewArgs) -> anyhow::Result<()> {
    if args.bench {
        return bench::run(&args);
    }
    if args.headless {
        return headless::run(&args);
    }
    window::run(args)
}
