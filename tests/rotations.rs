//! The default's diffuse error on maps it was not tuned on: every map of tests/data and every hard
//! sky turned 90° and 200° about the vertical and tipped 20° about +X, at N = 16 to 256, as a
//! ratio to converged k-means (ALGORITHMS.md §10). A yaw moves the sky across the lat-long grid and
//! the domain square's texels; a pitch also moves what lies above the horizon. `--ignored`: the
//! measurement behind docs/EVALUATION.md "Rotations of every map".

mod common;

use common::{every_map, worst_first};
use glam::DQuat;
use vemlight::eval::scenes::LatLongDirs;
use vemlight::lights::error::IrradianceReference;
use vemlight::lights::{ExtractOptions, Extractor, Method};
use vemlight::mapping::Domain;

/// Every case prints its ratio; the worst is named. The bounds are loose (the worst is 1.36 ×
/// where the target is 1.25, one case over it): they catch a placement that falls apart on
/// turned maps.
#[test]
#[ignore]
fn rotation_table() {
    let maps = every_map();
    let turns = [
        ("yaw 90°", DQuat::from_rotation_y(90f64.to_radians())),
        ("yaw 200°", DQuat::from_rotation_y(200f64.to_radians())),
        ("pitch 20°", DQuat::from_rotation_x(20f64.to_radians())),
    ];
    let mut rows = Vec::new();
    for (name, src) in &maps {
        let dirs = LatLongDirs::new(src.width, src.height);
        for (turn, rot) in turns {
            let map = dirs.rotated(src, rot);
            let reference = IrradianceReference::from_map(&map, Domain::Sphere);
            for n in [16, 32, 64, 128, 256] {
                let err = |m| {
                    let opts = ExtractOptions {
                        lights: n,
                        domain: Domain::Sphere,
                        method: m,
                        side: None,
                    };
                    reference
                        .error(&Extractor::new().extract(&map, &opts).lights)
                        .rel_rms
                };
                let ratio = err(Method::Voronoi) / err(Method::KMeans);
                eprintln!("{name:<22} {turn:<10} N={n:<4} {ratio:.3} × k-means");
                rows.push((ratio, format!("{name} {turn} N={n}")));
            }
        }
    }
    let worst = worst_first(&mut rows);
    let over = rows.iter().filter(|r| r.0 > 1.25).count();
    eprintln!(
        "{} cases, {over} over 1.25 × k-means; worst: {worst}",
        rows.len()
    );
    assert!(rows[0].0 <= 1.45, "worst {:.3}: {}", rows[0].0, rows[0].1);
    assert!(over <= 3, "{over} cases over 1.25 × k-means");
}
