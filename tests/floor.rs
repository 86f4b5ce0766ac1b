//! How firm the floor is: converged k-means (ALGORITHMS.md §10) lands in a fixed point that
//! depends on its k-means++ seeds, and other draws of the seeding generator land in other ones,
//! some lower. Every map of tests/data and every hard sky at N = 16 to 128, five draws: the
//! default's error over draw 0's (the evaluation's floor) and over the lowest of the five.
//! `--ignored`: the measurement behind docs/EVALUATION.md "How firm the floor is".

mod common;

use common::{every_map, worst_first};
use vemlight::lights::error::IrradianceReference;
use vemlight::lights::{ExtractOptions, Extractor, Method};
use vemlight::mapping::Domain;

const DRAWS: u64 = 5;

/// Every case prints its ratios; the worst against the lowest draw is named. The bound is loose
/// (the worst measured is about 1.2 ×, the target 1.25 × against draw 0): it catches a default
/// that only meets its target through an unlucky floor.
#[test]
#[ignore]
fn floor_table() {
    let maps = every_map();
    let mut rows = Vec::new();
    let mut spread: f64 = 1.0;
    for (name, map) in &maps {
        let reference = IrradianceReference::from_map(map, Domain::Sphere);
        for n in [16, 32, 64, 128] {
            let opts = |method| ExtractOptions {
                lights: n,
                domain: Domain::Sphere,
                method,
                side: None,
            };
            let ours = reference
                .error(&Extractor::new().extract(map, &opts(Method::Voronoi)).lights)
                .rel_rms;
            let draws: Vec<f64> = (0..DRAWS)
                .map(|draw| {
                    let mut ex = Extractor::new();
                    ex.set_kmeans_draw(draw);
                    reference
                        .error(&ex.extract(map, &opts(Method::KMeans)).lights)
                        .rel_rms
                })
                .collect();
            let lowest = draws.iter().copied().fold(f64::INFINITY, f64::min);
            eprintln!(
                "{name:<22} N={n:<4} {:.3} × draw 0, {:.3} × the lowest draw (draw 0 {:.3} × it)",
                ours / draws[0],
                ours / lowest,
                draws[0] / lowest
            );
            spread = spread.max(draws[0] / lowest);
            rows.push((ours / lowest, format!("{name} N={n}")));
        }
    }
    let worst = worst_first(&mut rows);
    let over = rows.iter().filter(|r| r.0 > 1.25).count();
    eprintln!(
        "{} cases; draw 0 up to {spread:.2} × the lowest of {DRAWS}; against the lowest, {over} over 1.25; worst: {worst}",
        rows.len()
    );
    assert!(rows[0].0 <= 1.4, "worst {:.3}: {}", rows[0].0, rows[0].1);
}
