//! The default on scenes lit by lamps, drawn at random (`eval::scenes::lamp_scene`): night
//! streets (a moon and street lamps), rooms of ceiling lamps, and studios of large softboxes, four
//! of each, as drawn and turned 37°, at N = 16 to 256: the diffuse error as a ratio to converged
//! k-means (ALGORITHMS.md §10) and the shadowed error as a ratio to median cut's (§9). The real
//! maps have few of these; the sky sweep (tests/skies.rs) none. `--ignored` (about 4 minutes on
//! two cores): the measurement behind docs/EVALUATION.md "Scenes lit by lamps".

mod common;

use vemlight::eval::scenes::{LampScene, lamp_scene};

const SEEDS: u64 = 4;
const COUNTS: [usize; 5] = [16, 32, 64, 128, 256];

/// Every case prints its two ratios; per N the worst are named and the cases over the targets
/// (1.25 × k-means, 1 × median cut) counted. The bounds are loose (the worst today are 1.39 ×
/// k-means and 1.13 × median cut's shadowed error): they catch a placement that falls apart on
/// a kind of scene.
#[test]
#[ignore = "measurement: prints the default against both anchors on 24 lamp-lit scenes (minutes)"]
fn lamp_scene_sweep() {
    let mut jobs: Vec<(LampScene, u64, f64)> = Vec::new();
    for kind in LampScene::ALL {
        for seed in 0..SEEDS {
            for yaw_deg in [0.0, 37.0] {
                jobs.push((kind, seed, yaw_deg));
            }
        }
    }
    let rows = common::sweep(&jobs, &COUNTS, |&(kind, seed, yaw_deg)| {
        let name = format!("{}-{seed} turned {yaw_deg}°", kind.name());
        (
            name,
            common::turned_about_y(lamp_scene(kind, seed, 1024), yaw_deg),
        )
    });
    let (worst_diffuse, worst_shadowed) = common::report_sweep("scenes", &rows, &COUNTS);
    assert!(worst_diffuse <= 1.6, "worst diffuse {worst_diffuse:.3}");
    assert!(worst_shadowed <= 1.6, "worst shadowed {worst_shadowed:.3}");
}
