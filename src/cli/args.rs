//! The flags several commands share: how lights are extracted (`lights`, `serve`) and how the
//! input's pixels map to directions. A leaf: the commands import it, it imports none of them.

use crate::envmap::Projection;
use crate::lights::Method;
use crate::mapping::Domain;
use anyhow::bail;

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
    /// Extra Lloyd steps of the voronoi method (more accurate, one assignment pass each; a single
    /// map of 65 to 192 lights takes twice as many).
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
