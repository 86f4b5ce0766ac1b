//! `vemlight bench`: per-frame extraction speed of every method, as medians and ratios to median
//! cut measured in the same run (see [`crate::eval::speed`]).

use crate::envmap::{DEFAULT_MAX_PIXELS, EnvMap, Projection};
use anyhow::Context;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct BenchArgs {
    /// A lat-long map; the fisheye case sees it through a 180° equidistant lens.
    #[arg(long, default_value = "tests/data/sunrise.exr")]
    pub map: PathBuf,
    /// Lights per frame (1–1024).
    #[arg(long, default_value_t = 256, value_parser = clap::value_parser!(u16).range(1..=1024))]
    pub lights: u16,
    /// Interleaved rounds; each times every case `--per-round` times.
    #[arg(long, default_value_t = 15, value_parser = clap::value_parser!(u16).range(1..))]
    pub rounds: u16,
    /// Timed runs of each case in a round.
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u16).range(1..))]
    pub per_round: u16,
}

/// `vemlight bench`.
pub fn run(args: BenchArgs) -> anyhow::Result<()> {
    use crate::eval::speed;
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
    let cases = speed::standard_cases(&map, usize::from(args.lights));
    println!(
        "{:<48} {:>10} {:>12} {:>9} {:>13} {:>22}",
        "case (single thread, decode excluded)",
        "median ms",
        "resample ms",
        "frames/s",
        "x median cut",
        "x median cut, bare †"
    );
    for t in speed::run(
        &cases,
        usize::from(args.rounds),
        usize::from(args.per_round),
    ) {
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
