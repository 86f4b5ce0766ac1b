//! The default on synthetic skies it was not tuned on: the built-in Hosek-Wilkie sky with a
//! real-size sun at eight elevations (2° to 60°), three turbidities (clear 2, hazy 5, very hazy 9)
//! and three cloud covers (none, 30 %, 70 %), 72 skies, at N = 16 to 256: the diffuse error as a
//! ratio to converged k-means (ALGORITHMS.md §10) and the shadowed error as a ratio to median
//! cut's (§9). The evaluation's five hard skies are four points of this grid's kind; the sweep
//! asks whether what holds on them holds between them; a second sweep turns them 37° off the
//! lat-long seam the model's sun sits on. `--ignored` (13 minutes each on two cores): the
//! measurement behind docs/EVALUATION.md "A sweep of synthetic skies".

mod common;

use vemlight::eval::scenes::still_sky;

const ELEVATIONS: [f64; 8] = [2.0, 4.0, 9.0, 15.0, 25.0, 35.0, 48.0, 60.0];
const TURBIDITIES: [f64; 3] = [2.0, 5.0, 9.0];
const CLOUDS: [f64; 3] = [0.0, 0.3, 0.7];
const COUNTS: [usize; 5] = [16, 32, 64, 128, 256];

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
    let rows = common::sweep(&jobs, &COUNTS, |&(e, t, c)| {
        let name = format!("sun {e}° turbidity {t} clouds {c} turned {yaw_deg}°");
        (
            name,
            common::turned_about_y(still_sky(1024, e, t, c), yaw_deg),
        )
    });
    let (worst_diffuse, worst_shadowed) = common::report_sweep("skies", &rows, &COUNTS);
    assert!(worst_diffuse <= 1.5, "worst diffuse {worst_diffuse:.3}");
    assert!(worst_shadowed <= 2.5, "worst shadowed {worst_shadowed:.3}");
}
