//! `vemlight eval`: regenerates docs/EVALUATION.md and docs/eval/ (see [`crate::eval`]).

use std::path::PathBuf;

#[derive(clap::Args)]
pub struct EvalArgs {
    /// Directory of lat-long .exr/.hdr maps.
    #[arg(long, default_value = "tests/data")]
    pub maps: PathBuf,
    /// Output directory for CSV, SVG and markdown tables.
    #[arg(long, default_value = "docs/eval")]
    pub out: PathBuf,
    /// Document whose generated sections (<!-- BEGIN name --> … <!-- END name -->) are rewritten;
    /// skipped when it does not exist.
    #[arg(long, default_value = "docs/EVALUATION.md")]
    pub doc: PathBuf,
    /// Fewer light counts, one timing run, 16 frames per sequence: a smoke run.
    #[arg(long)]
    pub quick: bool,
    /// Also evaluate lights restricted to the upper hemisphere.
    #[arg(long)]
    pub upper: bool,
}

/// `vemlight eval`.
pub fn run(args: EvalArgs) -> anyhow::Result<()> {
    let summary = crate::eval::run(&crate::eval::EvalOptions {
        maps: args.maps,
        out: args.out,
        doc: Some(args.doc),
        quick: args.quick,
        upper: args.upper,
    })?;
    println!("{summary}");
    Ok(())
}
