//! `max_error=E` on a single map (`vemlight lights --max-error`, `POST /v1/lights`): the fewest
//! lights whose estimated diffuse error meets E, against the powers of two the search starts from.
//! `--ignored` prints, per map and target, the count chosen and the smallest power of two that
//! meets E, each one's true diffuse error (ALGORITHMS.md §8) and shadowed error as a ratio to
//! median cut's at the same count (§9): the measurement behind PERFORMANCE.md "The adaptive light
//! count". `cargo test --release --test max_error -- --ignored --nocapture` (about a minute on
//! two cores for the 13 maps, five with the 18 held out; `VEMLIGHT_EXTRA_MAPS=DIR` adds a
//! directory of maps, such as the held-out ones of `scripts/heldout-maps.sh`).

mod common;

use std::sync::Mutex;
use vemlight::envmap::EnvMap;
use vemlight::eval::accuracy::Truth;
use vemlight::lights::{ExtractOptions, Extractor, Method};
use vemlight::lightset::{LightRequest, lightset_for_map};
use vemlight::mapping::Domain;

const TARGETS: [f64; 5] = [0.05, 0.02, 0.01, 0.005, 0.002];

/// One case: the count and its (true diffuse error, shadowed ÷ median cut's), for the count chosen
/// and for the smallest power of two that meets the target.
struct Case {
    map: String,
    target: f64,
    chosen: (usize, f64, f64),
    power: (usize, f64, f64),
}

#[test]
#[ignore = "measurement: prints the counts max_error chooses and their errors (minutes)"]
fn max_error_table() {
    let maps: Vec<(String, EnvMap)> = common::every_map_and_extra();
    let cases: Mutex<Vec<Case>> = Mutex::new(Vec::new());
    common::on_each(&maps, |(name, map)| {
        let truth = Truth::new(map, Domain::Sphere);
        let run = |method, lights| {
            let opts = ExtractOptions {
                lights,
                domain: Domain::Sphere,
                method,
                side: None,
            };
            Extractor::new().extract(map, &opts).lights
        };
        let errors = |lights: &[vemlight::lights::Light], n| {
            let median_cut = truth.shadowed_mean(&run(Method::MedianCut, n));
            (
                n,
                truth.diffuse.error(lights).rel_rms,
                truth.shadowed_mean(lights) / median_cut,
            )
        };
        let mut line = format!("{name:<24}");
        for target in TARGETS {
            let req = LightRequest {
                lights: 256,
                max_error: Some(target),
                ..LightRequest::default()
            };
            let set = lightset_for_map(&mut Extractor::new(), map, &req, name);
            let n = set.lights.len();
            let chosen = errors(&set.lights, n);
            let p = n.next_power_of_two();
            let power = if p == n {
                chosen
            } else {
                errors(&run(Method::Voronoi, p), p)
            };
            line += &format!(
                " | {target}: {n} ({:.4}, {:.2} ×) vs {p} ({:.4}, {:.2} ×)",
                chosen.1, chosen.2, power.1, power.2
            );
            cases.lock().expect("cases").push(Case {
                map: name.to_string(),
                target,
                chosen,
                power,
            });
        }
        eprintln!("{line}");
    });
    let cases = cases.into_inner().expect("cases");
    let total = |f: fn(&Case) -> usize| cases.iter().map(f).sum::<usize>();
    let (chosen, powers) = (total(|c| c.chosen.0), total(|c| c.power.0));
    eprintln!(
        "{} cases: {chosen} lights chosen against {powers} for the powers of two ({:.2} ×)",
        cases.len(),
        chosen as f64 / powers as f64
    );
    for target in TARGETS {
        let at: Vec<&Case> = cases.iter().filter(|c| c.target == target).collect();
        let mean =
            |f: fn(&Case) -> usize| at.iter().map(|c| f(c)).sum::<usize>() as f64 / at.len() as f64;
        eprintln!(
            "E = {target}: mean {:.1} lights chosen, {:.1} for the powers of two",
            mean(|c| c.chosen.0),
            mean(|c| c.power.0)
        );
    }
    // The range for the shadowed target: 16 lights and more.
    let over = |pick: fn(&Case) -> (usize, f64, f64)| {
        let mut from_16: Vec<(f64, String)> = cases
            .iter()
            .filter(|c| pick(c).0 >= 16)
            .map(|c| {
                (
                    pick(c).2,
                    format!("{} E {} at {}", c.map, c.target, pick(c).0),
                )
            })
            .collect();
        let n = from_16.iter().filter(|r| r.0 > 1.0).count();
        let cases = from_16.len();
        format!(
            "{n} of {cases} over median cut's, worst {}",
            common::worst_first(&mut from_16)
        )
    };
    eprintln!(
        "shadowed at 16 lights or more: chosen {}; powers of two {}",
        over(|c| c.chosen),
        over(|c| c.power)
    );
    let true_over = |pick: fn(&Case) -> (usize, f64, f64)| {
        let ratios: Vec<f64> = cases.iter().map(|c| pick(c).1 / c.target).collect();
        (
            ratios.iter().filter(|&&r| r > 1.0).count(),
            ratios.iter().cloned().fold(0.0, f64::max),
        )
    };
    let (a, b) = (true_over(|c| c.chosen), true_over(|c| c.power));
    eprintln!(
        "true diffuse error over E (the target is on the estimate): chosen {} cases, worst {:.2} × E; powers of two {} cases, worst {:.2} × E",
        a.0, a.1, b.0, b.1
    );
    assert!(
        chosen <= powers,
        "the search chose more lights than the powers of two"
    );
}
