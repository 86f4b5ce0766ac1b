//! Accuracy × speed of every method on a set of maps (`vemlight eval`, accuracy.csv).
//!
//! Input: decoded maps. Output: one [`AccuracyRow`] per (map, domain, method, N): diffuse error
//! (relative RMS and max over [`ERROR_NORMALS`](crate::lights::error::ERROR_NORMALS) Fibonacci
//! normals), glossy error (Phong 32 and 128), and the median single-thread time per frame
//! (resampling included, decoding excluded), against ground truth by brute force over every source
//! pixel (ALGORITHMS.md §8). The L2 SH irradiance is one more row per map (diffuse only, no lights).

use super::shadowed::{ShadowReference, ShadowScene, scenes, sky_emitters};
use super::speed::median;
use crate::envmap::EnvMap;
use crate::lights::error::{
    DiffuseError, GLOSSY_EXPONENTS, GlossyReference, IrradianceReference, map_emitters,
};
use crate::lights::{ExtractOptions, Extractor, Light, Method, sh};
use crate::mapping::Domain;
use crate::sampling::Resampler;
use std::time::Instant;

/// Light counts of the charts: 8 … 1024, powers of two.
pub const COUNTS: [usize; 8] = [8, 16, 32, 64, 128, 256, 512, 1024];

/// `a` over the anchor `b`, as every table's ratios are given: 1 where both are 0 (a black map,
/// a still sequence), ∞ where only the anchor is.
pub fn ratio(a: f64, b: f64) -> f64 {
    if b > 0.0 {
        a / b
    } else if a > 0.0 {
        f64::INFINITY
    } else {
        1.0
    }
}

/// The name of the SH reference line in tables and charts.
pub const SH_NAME: &str = "sh-l2";

/// One measurement.
#[derive(Clone, Debug)]
pub struct AccuracyRow {
    pub map: String,
    pub domain: Domain,
    /// A [`Method::name`] or [`SH_NAME`].
    pub method: String,
    /// Light count (`None` for SH: 9 coefficients, no lights).
    pub lights: Option<usize>,
    pub diffuse: DiffuseError,
    /// Relative RMS of the glossy error for each of [`GLOSSY_EXPONENTS`] (`None` for SH, which has
    /// no glossy answer).
    pub glossy: [Option<f64>; 2],
    /// Median seconds per frame, single thread.
    pub time_s: f64,
    /// Shadowed error (ALGORITHMS.md §9): relative RMS per scene of [`super::shadowed::scenes`],
    /// at the counts of [`SHADOW_COUNTS`] (empty elsewhere and for SH).
    pub shadowed: Vec<f64>,
    /// Lights that carry energy.
    pub alive: usize,
}

impl AccuracyRow {
    /// The shadowed error averaged over the scenes, if measured.
    pub fn shadowed_mean(&self) -> Option<f64> {
        (!self.shadowed.is_empty())
            .then(|| self.shadowed.iter().sum::<f64>() / self.shadowed.len() as f64)
    }
}

/// Light counts at which the shadowed error is measured (it costs a ray per light per probe).
pub const SHADOW_COUNTS: [usize; 5] = [16, 32, 64, 128, 256];

/// Probe spacing of the shadow scenes, metres.
pub const SHADOW_PROBE_STEP: f64 = 0.25;

/// Ground truth of one map in one domain.
pub struct Truth {
    pub diffuse: IrradianceReference,
    pub glossy: [GlossyReference; 2],
    /// The shadow scenes and their references (sphere domain only: the ground sees the sky).
    pub shadow: Vec<(ShadowScene, ShadowReference)>,
}

impl Truth {
    /// Brute force over every pixel of the map inside the domain.
    pub fn new(map: &EnvMap, domain: Domain) -> Self {
        let emitters = map_emitters(map, domain);
        let sky = sky_emitters(map);
        Truth {
            diffuse: IrradianceReference::from_emitters(&emitters),
            glossy: GLOSSY_EXPONENTS.map(|e| GlossyReference::from_emitters(&emitters, e)),
            shadow: scenes(SHADOW_PROBE_STEP)
                .into_iter()
                .map(|s| {
                    let r = ShadowReference::new(&s, &sky);
                    (s, r)
                })
                .collect(),
        }
    }

    /// The shadowed error of `lights` in every scene.
    pub fn shadowed(&self, lights: &[Light]) -> Vec<f64> {
        self.shadow
            .iter()
            .map(|(s, r)| r.error(s, lights))
            .collect()
    }

    /// The shadowed error of `lights`, the mean over the scenes (0 with none), as the evaluation
    /// reports it.
    pub fn shadowed_mean(&self, lights: &[Light]) -> f64 {
        let per_scene = self.shadowed(lights);
        per_scene.iter().sum::<f64>() / per_scene.len().max(1) as f64
    }
}

/// One [`Extractor`] per method, kept across maps so per-count tables (the paper variant's cell
/// grids) are built once, outside the timing.
pub fn extractors() -> Vec<Extractor> {
    Method::ALL.iter().map(|_| Extractor::new()).collect()
}

/// Every method at every count on one map, plus the SH line; `reps` timed runs per case after one
/// untimed warm-up, `tick` called after each method. `extractors` comes from [`extractors`].
#[allow(clippy::too_many_arguments)]
pub fn evaluate_map(
    extractors: &mut [Extractor],
    name: &str,
    map: &EnvMap,
    domain: Domain,
    truth: &Truth,
    counts: &[usize],
    reps: usize,
    mut tick: impl FnMut(),
) -> Vec<AccuracyRow> {
    let mut rows = Vec::new();
    for (method, ex) in Method::ALL.into_iter().zip(extractors) {
        for &n in counts {
            let opts = ExtractOptions {
                lights: n,
                domain,
                method,
                side: None,
            };
            let mut out = ex.extract(map, &opts);
            // k-means is the floor, not a contender for speed: one run.
            let reps = if method == Method::KMeans { 1 } else { reps };
            let mut times: Vec<f64> = (0..reps.max(1))
                .map(|_| {
                    let t = Instant::now();
                    out = ex.extract(map, &opts);
                    t.elapsed().as_secs_f64()
                })
                .collect();
            rows.push(AccuracyRow {
                map: name.to_string(),
                domain,
                method: method.name().to_string(),
                lights: Some(n),
                diffuse: truth.diffuse.error(&out.lights),
                glossy: [0, 1].map(|k| Some(truth.glossy[k].error(&out.lights).rel_rms)),
                time_s: median(&mut times),
                shadowed: if SHADOW_COUNTS.contains(&n) {
                    truth.shadowed(&out.lights)
                } else {
                    Vec::new()
                },
                alive: out.lights.iter().filter(|l| l.carries_energy()).count(),
            });
        }
        tick();
    }
    rows.push(sh_row(name, map, domain, truth, reps));
    tick();
    rows
}

/// The L2 SH reference: resample, project, evaluate RH01 irradiance at the normals.
fn sh_row(name: &str, map: &EnvMap, domain: Domain, truth: &Truth, reps: usize) -> AccuracyRow {
    let mut resampler = Resampler::new(map.projection, map.width, map.height, domain, None);
    let mut image = resampler.resample(map);
    let mut coeffs = sh::project(&image);
    let mut times: Vec<f64> = (0..reps.max(1))
        .map(|_| {
            let t = Instant::now();
            resampler.resample_into(map, &mut image);
            coeffs = sh::project(&image);
            t.elapsed().as_secs_f64()
        })
        .collect();
    let estimate: Vec<f64> = truth
        .diffuse
        .normals()
        .iter()
        .map(|&n| crate::envmap::luminance64(sh::irradiance(&coeffs, n)))
        .collect();
    AccuracyRow {
        map: name.to_string(),
        domain,
        method: SH_NAME.to_string(),
        lights: None,
        diffuse: truth.diffuse.error_of(&estimate),
        glossy: [None, None],
        time_s: median(&mut times),
        shadowed: Vec::new(),
        alive: 0,
    }
}

/// accuracy.csv.
pub fn to_csv(rows: &[AccuracyRow]) -> String {
    let mut s = String::from(
        "map,domain,method,lights,diffuse_rel_rms,diffuse_rel_max,glossy32_rel_rms,glossy128_rel_rms,time_ms,shadowed_rel_rms,lights_with_energy\n",
    );
    let opt = |v: Option<f64>| v.map(|v| format!("{v:.6}")).unwrap_or_default();
    for r in rows {
        s += &format!(
            "{},{},{},{},{:.6},{:.6},{},{},{:.4},{},{}\n",
            r.map,
            r.domain.name(),
            r.method,
            r.lights.map(|n| n.to_string()).unwrap_or_default(),
            r.diffuse.rel_rms,
            r.diffuse.rel_max,
            opt(r.glossy[0]),
            opt(r.glossy[1]),
            r.time_s * 1e3,
            opt(r.shadowed_mean()),
            r.alive,
        );
    }
    s
}

/// Median, minimum and maximum over maps of one quantity for (domain, method, N).
#[derive(Clone, Copy, Debug)]
pub struct Spread {
    pub median: f64,
    pub min: f64,
    pub max: f64,
}

/// The spread over maps of `f` for the rows of one domain, method and count.
pub fn spread(
    rows: &[AccuracyRow],
    domain: Domain,
    method: &str,
    lights: Option<usize>,
    f: impl Fn(&AccuracyRow) -> Option<f64>,
) -> Option<Spread> {
    let mut v: Vec<f64> = rows
        .iter()
        .filter(|r| r.domain == domain && r.method == method && r.lights == lights)
        .filter_map(&f)
        .filter(|x| x.is_finite())
        .collect();
    if v.is_empty() {
        return None;
    }
    let min = v.iter().copied().fold(f64::INFINITY, f64::min);
    let max = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    Some(Spread {
        median: median(&mut v),
        min,
        max,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_black_map_meets_the_ratios() {
        assert_eq!(ratio(0.0, 0.0), 1.0);
        assert_eq!(ratio(1.0, 0.0), f64::INFINITY);
        assert_eq!(ratio(1.0, 2.0), 0.5);
    }
}
