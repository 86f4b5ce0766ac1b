//! The default on synthetic skies it was not tuned on: the built-in Hosek-Wilkie sky with a
//! real-size sun at eight elevations (2° to 60°), three turbidities (clear 2, hazy 5, very hazy 9)
//! and three cloud covers (none, 30 %, 70 %), 72 skies, at N = 16 to 256: the diffuse error as a
//! ratio to converged k-means (ALGORITHMS.md §10) and the shadowed error as a ratio to median
//! cut's (§9). The evaluation's five hard skies are four points of this grid's kind; the sweep
//! asks whether what holds on them holds between them; a second sweep turns them 37° off the
//! lat-long seam the model's sun sits on. `--ignored` (13 minutes each on two cores): the
//! measurement behind docs/EVALUATION.md "A sweep of synthetic skies".

mod common;

use common::worst_first;
use glam::DQuat;
use std::sync::Mutex;
use vemlight::eval::accuracy::Truth;
use vemlight::eval::scenes::{LatLongDirs, still_sky};
use vemlight::lights::{ExtractOptions, Extractor, Method};
use vemlight::mapping::Domain;

const ELEVATIONS: [f64; 8] = [2.0, 4.0, 9.0, 15.0, 25.0, 35.0, 48.0, 60.0];
const TURBIDITIES: [f64; 3] = [2.0, 5.0, 9.0];
const CLOUDS: [f64; 3] = [0.0, 0.3, 0.7];
const COUNTS: [usize; 5] = [16, 32, 64, 128, 256];

/// One case: (N, sky name, diffuse ÷ k-means, shadowed ÷ median cut).
type Row = (usize, String, f64, f64);

/// Every case prints its two ratios; per N the worst of each is named and the cases over the
/// targets (1.25 × k-means, 1 × median cut) counted. The bounds are loose (the worst today are
/// 1.36 × k-means and 1.96 × median cut's shadowed error): they catch a placement that falls
/// apart on a kind of sky.
#[test]
#[ignore]
fn sky_sweep() {
    sweep(0.0);
}

/// The same skies turned 37° about the vertical: the model's sun sits on the lat-long map's seam
/// (azimuth 180°), where median cut's first cut halves it; turned, it does not (worst today 1.27 ×
/// k-means and 1.99 × median cut's shadowed error).
#[test]
#[ignore]
fn sky_sweep_turned() {
    sweep(37.0);
}

/// The sweep, each sky turned `yaw_deg` about +Y.
fn sweep(yaw_deg: f64) {
    let mut jobs: Vec<(f64, f64, f64)> = Vec::new();
    for e in ELEVATIONS {
        for t in TURBIDITIES {
            for c in CLOUDS {
                jobs.push((e, t, c));
            }
        }
    }
    let rows: Mutex<Vec<Row>> = Mutex::new(Vec::new());
    common::on_each(&jobs, |&(e, t, c)| {
        let name = format!("sun {e}° turbidity {t} clouds {c} turned {yaw_deg}°");
        let map = still_sky(1024, e, t, c);
        let map = if yaw_deg == 0.0 {
            map
        } else {
            LatLongDirs::new(map.width, map.height)
                .rotated(&map, DQuat::from_rotation_y(yaw_deg.to_radians()))
        };
        let truth = Truth::new(&map, Domain::Sphere);
        for n in COUNTS {
            let errors = |m| {
                let opts = ExtractOptions {
                    lights: n,
                    domain: Domain::Sphere,
                    method: m,
                    side: None,
                };
                let lights = Extractor::new().extract(&map, &opts).lights;
                (
                    truth.diffuse.error(&lights).rel_rms,
                    truth.shadowed_mean(&lights),
                )
            };
            let ours = errors(Method::Voronoi);
            let diffuse = ours.0 / errors(Method::KMeans).0;
            let shadowed = ours.1 / errors(Method::MedianCut).1;
            eprintln!(
                "{name:<48} N={n:<4} diffuse {diffuse:.3} × k-means, shadowed {shadowed:.3} × median cut"
            );
            rows.lock()
                .expect("rows")
                .push((n, name.clone(), diffuse, shadowed));
        }
    });
    let rows = rows.into_inner().expect("rows");
    let (mut worst_diffuse, mut worst_shadowed) = (0.0f64, 0.0f64);
    for n in COUNTS {
        let at: Vec<&Row> = rows.iter().filter(|r| r.0 == n).collect();
        let mut diffuse: Vec<(f64, String)> = at.iter().map(|r| (r.2, r.1.clone())).collect();
        let mut shadowed: Vec<(f64, String)> = at.iter().map(|r| (r.3, r.1.clone())).collect();
        let over_d = diffuse.iter().filter(|r| r.0 > 1.25).count();
        let over_s = shadowed.iter().filter(|r| r.0 > 1.0).count();
        let (wd, ws) = (worst_first(&mut diffuse), worst_first(&mut shadowed));
        eprintln!(
            "N={n}: {} skies; diffuse over 1.25 × k-means: {over_d}, worst {wd}; shadowed over median cut's: {over_s}, worst {ws}",
            at.len()
        );
        worst_diffuse = worst_diffuse.max(diffuse[0].0);
        worst_shadowed = worst_shadowed.max(shadowed[0].0);
    }
    assert!(worst_diffuse <= 1.5, "worst diffuse {worst_diffuse:.3}");
    assert!(worst_shadowed <= 2.5, "worst shadowed {worst_shadowed:.3}");
}
