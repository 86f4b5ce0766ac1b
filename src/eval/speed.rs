//! `vemlight bench`: per-frame light extraction time, single thread, decoding excluded, against
//! median cut in the same run; and EXR decode time on its own.

use crate::envmap::{DEFAULT_MAX_PIXELS, EnvMap, Lens, Projection};
use crate::lights::{ExtractOptions, Extractor, Method};
use crate::mapping::Domain;
use std::time::Instant;

/// One timed case: a map, a method and a light count.
pub struct Case {
    pub name: String,
    pub map: EnvMap,
    pub opts: ExtractOptions,
    /// Run the extractor in video mode (`Extractor::set_video`), as the daemon does.
    pub video: bool,
}

/// Median time of one case, in seconds per frame.
#[derive(Clone, Debug)]
pub struct Timing {
    pub name: String,
    pub median_s: f64,
    /// Median over the baseline (median cut on the same map) measured in the same rounds.
    pub ratio_to_baseline: Option<f64>,
    /// Median of the resampling pass alone (part of `median_s`).
    pub resample_s: f64,
    /// Median over the baseline's time without its resampling pass, where the baseline does not
    /// use that pass (median cut reads a lat-long source directly): the honest ratio.
    pub ratio_to_bare_baseline: Option<f64>,
}

/// The standard speed cases: a 640×480 fisheye and a 1024×512 lat-long, 256 lights, every method.
pub fn standard_cases(latlong: &EnvMap, lights: usize) -> Vec<Case> {
    let fisheye = latlong.reproject(
        Projection::Fisheye {
            lens: Lens::Equidistant,
            fov_deg: 180.0,
            centre: None,
            radius: None,
        },
        640,
        480,
    );
    let mut cases = Vec::new();
    for (label, map, domain) in [
        ("fisheye 640x480", &fisheye, Domain::Upper),
        ("latlong 1024x512", latlong, Domain::Sphere),
    ] {
        for method in Method::STREAMING {
            cases.push(Case {
                name: format!("{label} -> {lights} lights, {}", method.name()),
                map: map.clone(),
                opts: ExtractOptions {
                    lights,
                    domain,
                    method,
                    side: None,
                },
                video: false,
            });
        }
        // The default as a stream runs it: one Lloyd step a frame from the last frame's lights.
        cases.push(Case {
            name: format!("{label} -> {lights} lights, voronoi stream"),
            map: map.clone(),
            opts: ExtractOptions {
                lights,
                domain,
                method: Method::Voronoi,
                side: None,
            },
            video: true,
        });
    }
    cases
}

/// Runs the cases in interleaved rounds (each round times every case `per_round` times) and
/// returns each case's median frame time; ratios are to the median-cut case on the same map.
pub fn run(cases: &[Case], rounds: usize, per_round: usize) -> Vec<Timing> {
    // One extractor per case, warmed up, so table building is not timed.
    let mut extractors: Vec<Extractor> = cases.iter().map(|_| Extractor::new()).collect();
    for (c, ex) in cases.iter().zip(&mut extractors) {
        ex.set_video(c.video);
        ex.extract(&c.map, &c.opts);
    }
    let mut samples: Vec<Vec<f64>> = vec![Vec::with_capacity(rounds * per_round); cases.len()];
    let mut resamples: Vec<Vec<f64>> = samples.clone();
    let mut bare: Vec<Vec<f64>> = samples.clone();
    for _ in 0..rounds {
        for (k, (c, ex)) in cases.iter().zip(&mut extractors).enumerate() {
            for _ in 0..per_round {
                let t = Instant::now();
                let out = ex.extract(&c.map, &c.opts);
                let total = t.elapsed().as_secs_f64();
                samples[k].push(total);
                resamples[k].push(out.timings.resample_s);
                bare[k].push(total - out.timings.resample_s);
                std::hint::black_box(out);
            }
        }
    }
    let medians: Vec<f64> = samples.iter_mut().map(|s| median(s)).collect();
    let resample: Vec<f64> = resamples.iter_mut().map(|s| median(s)).collect();
    let bare: Vec<f64> = bare.iter_mut().map(|s| median(s)).collect();
    cases
        .iter()
        .enumerate()
        .map(|(k, c)| {
            let baseline = cases.iter().position(|b| {
                b.opts.method == Method::MedianCut
                    && b.map.width == c.map.width
                    && b.map.height == c.map.height
            });
            Timing {
                name: c.name.clone(),
                median_s: medians[k],
                ratio_to_baseline: baseline.map(|b| medians[k] / medians[b]),
                resample_s: resample[k],
                ratio_to_bare_baseline: baseline
                    .filter(|&b| cases[b].map.projection == Projection::LatLong)
                    .map(|b| medians[k] / bare[b]),
            }
        })
        .collect()
}

/// Median time to decode a file's bytes into an [`EnvMap`].
pub fn decode_median(bytes: &[u8], runs: usize) -> f64 {
    let mut s: Vec<f64> = (0..runs)
        .map(|_| {
            let t = Instant::now();
            let m = EnvMap::decode(bytes, None, DEFAULT_MAX_PIXELS).expect("decodes");
            std::hint::black_box(m);
            t.elapsed().as_secs_f64()
        })
        .collect();
    median(&mut s)
}

pub fn median(s: &mut [f64]) -> f64 {
    if s.is_empty() {
        return f64::NAN;
    }
    s.sort_by(f64::total_cmp);
    let n = s.len();
    if n % 2 == 1 {
        s[n / 2]
    } else {
        0.5 * (s[n / 2 - 1] + s[n / 2])
    }
}
