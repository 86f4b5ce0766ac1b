//! Test helpers shared by the sky's unit tests: a sky of a given width, and the energies the tests
//! compare (with the solid angles of envmap.rs, independent of the sky's own grid tables).

use crate::envmap::{EnvMap, luminance64};
use crate::mapping::Domain;

use super::{SyntheticConfig, SyntheticSky};

/// The default sky at `width` × `width/2`, with `f` applied to its configuration.
pub(super) fn sky(width: usize, f: impl FnOnce(&mut SyntheticConfig)) -> SyntheticSky {
    let mut cfg = SyntheticConfig {
        width,
        height: width / 2,
        ..SyntheticConfig::default()
    };
    f(&mut cfg);
    SyntheticSky::new(cfg)
}

/// ∫ L dω over the pixels above the horizon, with the solid angles of envmap.rs.
pub(super) fn upper_integral(map: &EnvMap) -> [f64; 3] {
    let mut sum = [0.0; 3];
    for j in 0..map.height / 2 {
        for i in 0..map.width {
            let (_, sr) = map.projection.pixel(i, j, map.width, map.height).unwrap();
            for c in 0..3 {
                sum[c] += map.pixels[j * map.width + i][c] as f64 * sr;
            }
        }
    }
    sum
}

/// Luminance of ∫ L dω over the whole sphere.
pub(super) fn total(map: &EnvMap) -> f64 {
    luminance64(map.integral(Domain::Sphere))
}
