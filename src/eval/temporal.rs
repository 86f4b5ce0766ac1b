//! Temporal stability of every method on slowly changing sequences (`vemlight eval`, temporal.csv).
//!
//! Input: a [`Sequence`] of lat-long frames. Output: per method, with and without the FIR of
//! [`crate::temporal`], a [`TemporalRow`]:
//! - **flicker ratio** = Σ_t Σ_n |E_N(t+1, n) − E_N(t, n)| / Σ_t Σ_n |E(t+1, n) − E(t, n)|, the total
//!   variation of the irradiance from the lights at fixed normals over that of the true irradiance
//!   (ALGORITHMS.md §8; 1 is perfect). Total variation, not RMS, so a filter that spreads a true step
//!   over frames is not rewarded for it, while jitter on top of a true change always costs. Both
//!   variants skip the filter's first M − 1 frames (its warm-up), and the filtered series is compared
//!   with the truth delayed by the filter's nominal group delay, so that a lagging but exact estimate
//!   of a ramp scores 1, not (shorter ramp)/(longer ramp);
//! - the lights' angular speed per id (mean and 99th percentile, degrees per frame; for median cut
//!   id k is the k-th region of the split order, which is not the same region from frame to frame,
//!   so its "speed" measures popping);
//! - the filter's delay: nominal group delay, and measured as the lag (0 … 12 frames) that best
//!   aligns E_N with E;
//! - the mean relative RMS error of E_N against the same frame's E.
//!
//! A map turned at a constant rate also gets the **rigid** anchor ([`RIGID_NAME`]): the default's
//! first-frame lights turned exactly with the map, at each frame's energy, raw and through the
//! same FIR. It is what perfect tracking of that light set would give: point lights err between
//! their directions, and a normal sweeping through that error sees E_N wobble where E does not,
//! so its flicker is the floor of the set, not 1.
//!
//! Ground truth per frame: brute force over the frame's pixels binned 4 × 4 (each bin an emitter at
//! its luminance-weighted mean direction, so the binning error is second order: below 10⁻⁴ relative
//! for diffuse irradiance), at [`TEMPORAL_NORMALS`] Fibonacci normals — fewer than the accuracy
//! part's 256, to keep the whole evaluation within its time budget.

use super::accuracy::{SH_NAME, ratio};
use super::scenes::angle_deg;
use crate::envmap::{EnvMap, luminance64};
use crate::lights::error::fibonacci_sphere;
use crate::lights::{ExtractOptions, Extractor, Light, Method, sh};
use crate::mapping::Domain;
use crate::sampling::Resampler;
use crate::temporal::{FilterSpec, TemporalFilter};
use glam::{DQuat, DVec3, Vec3};

/// Normals at which E and E_N are compared in the temporal part.
pub const TEMPORAL_NORMALS: usize = 64;
/// Pixels per side of a ground-truth bin.
const TRUTH_BIN: usize = 4;
/// Largest lag searched when measuring the delay, frames.
const MAX_LAG: usize = 12;
/// The method name of the rigid anchor's rows.
pub const RIGID_NAME: &str = "rigid";

/// A named sequence of frames, rendered on demand (frames are not all held in memory).
pub struct Sequence<'a> {
    pub name: String,
    pub description: String,
    pub frames: usize,
    pub render: Box<dyn FnMut(usize) -> EnvMap + 'a>,
    /// For a map turned at a constant rate, the turn from one frame to the next (frame t is the
    /// map turned by its t-th power): the rigid anchor turns the first frame's lights with it.
    pub turn_per_frame: Option<DQuat>,
}

/// The measurements of one method (and filter) on one sequence.
#[derive(Clone, Debug)]
pub struct TemporalRow {
    pub sequence: String,
    pub method: String,
    /// "none" or "fir" (the default 9-tap binomial).
    pub filter: &'static str,
    pub lights: usize,
    pub flicker: f64,
    pub rel_rms: f64,
    pub speed_mean_deg: f64,
    pub speed_p99_deg: f64,
    /// Largest per-id jump between consecutive frames, degrees.
    pub speed_max_deg: f64,
    /// Where that jump was: the frame it ended on and the light id (none without lights).
    pub speed_max_at: Option<(usize, u32)>,
    pub delay_nominal: f64,
    pub delay_measured: usize,
}

/// What a track's series comes from.
#[derive(Clone, Copy, PartialEq)]
enum Source {
    /// The variant of that index.
    Variant(usize),
    /// The SH reference line.
    Sh,
    /// The default's first-frame lights, turned with the map.
    Rigid,
}

/// State of one (source, filter) pair while a sequence runs.
struct Track {
    source: Source,
    filter: Option<TemporalFilter>,
    series: Vec<Vec<f64>>,
    prev: Vec<Light>,
    speeds: Vec<f64>,
    /// Largest jump so far: degrees, frame, id.
    worst: Option<(f64, usize, u32)>,
}

/// One extractor to run over a sequence, named by `label` in the rows.
pub struct Variant {
    pub label: String,
    pub method: Method,
    pub extractor: Extractor,
}

/// Runs every method on the sequence at `n` lights; `with_fir` adds the filtered variants.
/// `tick` is called after every frame.
pub fn run_sequence(
    seq: &mut Sequence,
    n: usize,
    domain: Domain,
    with_fir: bool,
    tick: impl FnMut(),
) -> Vec<TemporalRow> {
    let variants = Method::STREAMING
        .iter()
        .map(|&method| {
            // A sequence is a video: the default runs as the daemon runs it
            // (`Extractor::set_video`).
            let mut extractor = Extractor::new();
            extractor.set_video(true);
            Variant {
                label: method.name().to_string(),
                method,
                extractor,
            }
        })
        .collect();
    run_variants(seq, n, domain, with_fir, variants, true, tick)
}

/// Runs each of `variants` (extractors set up by the caller) on the sequence at `n` lights;
/// `with_fir` adds the filtered rows, `with_sh` the SH reference line.
pub fn run_variants(
    seq: &mut Sequence,
    n: usize,
    domain: Domain,
    with_fir: bool,
    mut variants: Vec<Variant>,
    with_sh: bool,
    mut tick: impl FnMut(),
) -> Vec<TemporalRow> {
    let normals = fibonacci_sphere(TEMPORAL_NORMALS);
    let fir = FilterSpec::default();
    let mut tracks: Vec<Track> = Vec::new();
    let track = |source, filter| Track {
        source,
        filter,
        series: Vec::new(),
        prev: Vec::new(),
        speeds: Vec::new(),
        worst: None,
    };
    // The rigid anchor follows the default (its variant's index), where the sequence is a
    // constant turn (the step).
    let rigid = seq.turn_per_frame.and_then(|step| {
        let v = variants.iter().position(|v| v.method == Method::Voronoi)?;
        Some((v, step))
    });
    let sources = (0..variants.len())
        .map(Source::Variant)
        .chain(rigid.map(|_| Source::Rigid));
    for source in sources {
        for filtered in [false, true] {
            if filtered && !with_fir {
                continue;
            }
            tracks.push(track(source, filtered.then(|| TemporalFilter::new(&fir))));
        }
    }
    if with_sh {
        // The SH reference line: no lights, no filter.
        tracks.push(track(Source::Sh, None));
    }
    let mut first_frame: Vec<Light> = Vec::new();
    let mut turn = DQuat::IDENTITY;
    let mut rigid_lights: Vec<Light> = Vec::new();
    let mut resampler: Option<Resampler> = None;
    let mut truth_series = Vec::with_capacity(seq.frames);

    for t in 0..seq.frames {
        let map = (seq.render)(t);
        truth_series.push(truth(&map, domain, &normals));
        let outs: Vec<Vec<Light>> = variants
            .iter_mut()
            .map(|v| {
                let opts = ExtractOptions {
                    lights: n,
                    domain,
                    method: v.method,
                    side: None,
                };
                v.extractor.extract(&map, &opts).lights
            })
            .collect();
        if let Some((v, step)) = rigid {
            if t == 0 {
                first_frame = outs[v].clone();
            } else {
                turn = (step * turn).normalize();
            }
            // At the frame's own energy: the resampling of a turned map makes a sub-pixel
            // source's energy wobble from frame to frame (most under pitch), which the truth and
            // every energy-conserving method follow.
            let energy = |ls: &[Light]| ls.iter().map(Light::luminance).sum::<f64>();
            let scale = energy(&outs[v]) / energy(&first_frame);
            rigid_lights = turned(
                &first_frame,
                turn,
                if scale.is_finite() { scale } else { 1.0 },
            );
        }
        for tr in &mut tracks {
            let raw: &[Light] = match tr.source {
                Source::Variant(v) => &outs[v],
                Source::Rigid => &rigid_lights,
                Source::Sh => &[],
            };
            if tr.source == Source::Sh {
                let r = resampler.get_or_insert_with(|| {
                    Resampler::new(map.projection, map.width, map.height, domain, None)
                });
                let c = sh::project(&r.resample(&map));
                tr.series.push(
                    normals
                        .iter()
                        .map(|&nrm| luminance64(sh::irradiance(&c, nrm)))
                        .collect(),
                );
                continue;
            };
            let lights = match &mut tr.filter {
                Some(f) => f.filter(raw),
                None => raw.to_vec(),
            };
            tr.series.push(irradiance_at(&lights, &normals));
            if tr.prev.len() == lights.len() {
                for (a, b) in tr.prev.iter().zip(&lights) {
                    let deg = angle_deg(a.dir(), b.dir());
                    if tr.worst.is_none_or(|w| deg > w.0) {
                        tr.worst = Some((deg, t, b.id));
                    }
                    tr.speeds.push(deg);
                }
            }
            tr.prev = lights;
        }
        tick();
    }

    tracks
        .into_iter()
        .map(|mut tr| {
            let delay_nominal = if tr.filter.is_some() {
                fir.delay_frames()
            } else {
                0.0
            };
            let (mean, p99, max) = speed_stats(&mut tr.speeds);
            TemporalRow {
                sequence: seq.name.clone(),
                method: match tr.source {
                    Source::Variant(v) => variants[v].label.clone(),
                    Source::Rigid => RIGID_NAME.to_string(),
                    Source::Sh => SH_NAME.to_string(),
                },
                filter: if tr.filter.is_some() { "fir" } else { "none" },
                lights: if tr.source == Source::Sh { 0 } else { n },
                flicker: {
                    // Skip the warm-up; compare the filtered series with the delayed truth.
                    let warm = (fir.kernel().len() - 1).min(tr.series.len().saturating_sub(2));
                    let d = (delay_nominal.round() as usize).min(warm);
                    let end = tr.series.len();
                    flicker_ratio(&tr.series[warm..], &truth_series[warm - d..end - d])
                },
                rel_rms: mean_rel_rms(&tr.series, &truth_series, 0),
                speed_mean_deg: mean,
                speed_p99_deg: p99,
                speed_max_deg: max,
                speed_max_at: tr.worst.map(|w| (w.1, w.2)),
                delay_nominal,
                delay_measured: best_lag(&tr.series, &truth_series),
            }
        })
        .collect()
}

/// `lights` turned by `turn`, their power scaled by `scale`.
fn turned(lights: &[Light], turn: DQuat, scale: f64) -> Vec<Light> {
    lights
        .iter()
        .map(|l| Light {
            to_light: (turn * l.dir()).normalize().as_vec3().to_array(),
            irradiance: l.irradiance.map(|c| (c as f64 * scale) as f32),
            ..*l
        })
        .collect()
}

/// E_N (luminance) at each normal from a light set.
pub use crate::lights::error::irradiance_at;

/// True E (luminance) at each normal, by brute force over the frame's pixels binned
/// 4 × 4 (`TRUTH_BIN`) with their first moment kept.
pub fn truth(map: &EnvMap, domain: Domain, normals: &[DVec3]) -> Vec<f64> {
    let (bw, bh) = (
        map.width.div_ceil(TRUTH_BIN),
        map.height.div_ceil(TRUTH_BIN),
    );
    let mut bins = vec![(Vec3::ZERO, 0.0f32); bw * bh];
    for j in 0..map.height {
        for i in 0..map.width {
            if let Some((d, sr)) = map.projection.pixel(i, j, map.width, map.height)
                && domain.contains(d)
            {
                let y = EnvMap::luminance(map.pixels[j * map.width + i]) * sr as f32;
                if y > 0.0 {
                    let b = &mut bins[(j / TRUTH_BIN) * bw + i / TRUTH_BIN];
                    b.0 += d.as_vec3() * y;
                    b.1 += y;
                }
            }
        }
    }
    let emitters: Vec<(Vec3, f32)> = bins
        .into_iter()
        .filter(|b| b.1 > 0.0)
        .map(|(m, e)| (m.normalize_or(Vec3::Y), e))
        .collect();
    normals
        .iter()
        .map(|n| {
            let n = n.as_vec3();
            emitters
                .iter()
                .map(|(d, e)| (e * n.dot(*d).max(0.0)) as f64)
                .sum()
        })
        .collect()
}

/// Total variation of `series` over that of `truth` (both frames × normals); 1 when the truth does
/// not change and neither does the estimate, ∞ when only the estimate changes.
pub fn flicker_ratio(series: &[Vec<f64>], truth: &[Vec<f64>]) -> f64 {
    let tv = |s: &[Vec<f64>]| -> f64 {
        s.windows(2)
            .map(|w| {
                w[0].iter()
                    .zip(&w[1])
                    .map(|(a, b)| (b - a).abs())
                    .sum::<f64>()
            })
            .sum()
    };
    ratio(tv(series), tv(truth))
}

/// Mean over frames t ≥ lag of the relative RMS of series(t) against truth(t − lag).
fn mean_rel_rms(series: &[Vec<f64>], truth: &[Vec<f64>], lag: usize) -> f64 {
    let mut acc = 0.0;
    let mut count = 0;
    for t in lag..series.len() {
        let (mut num, mut den) = (0.0, 0.0);
        for (e, g) in series[t].iter().zip(&truth[t - lag]) {
            num += (e - g) * (e - g);
            den += g * g;
        }
        if den > 0.0 {
            acc += (num / den).sqrt();
            count += 1;
        }
    }
    if count > 0 { acc / count as f64 } else { 0.0 }
}

/// The lag (frames) at which the series best matches the truth.
fn best_lag(series: &[Vec<f64>], truth: &[Vec<f64>]) -> usize {
    (0..=MAX_LAG.min(series.len().saturating_sub(2)))
        .map(|lag| (lag, mean_rel_rms(series, truth, lag)))
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(lag, _)| lag)
        .unwrap_or(0)
}

fn speed_stats(speeds: &mut [f64]) -> (f64, f64, f64) {
    if speeds.is_empty() {
        return (0.0, 0.0, 0.0);
    }
    speeds.sort_by(f64::total_cmp);
    let mean = speeds.iter().sum::<f64>() / speeds.len() as f64;
    let p99 = speeds[((speeds.len() - 1) as f64 * 0.99).round() as usize];
    (mean, p99, speeds[speeds.len() - 1])
}

/// temporal.csv.
pub fn to_csv(rows: &[TemporalRow]) -> String {
    let mut s = String::from(
        "sequence,method,filter,lights,flicker_ratio,rel_rms,speed_mean_deg,speed_p99_deg,speed_max_deg,delay_nominal_frames,delay_measured_frames\n",
    );
    for r in rows {
        s += &format!(
            "{},{},{},{},{:.4},{:.5},{:.4},{:.4},{:.3},{},{}\n",
            r.sequence,
            r.method,
            r.filter,
            r.lights,
            r.flicker,
            r.rel_rms,
            r.speed_mean_deg,
            r.speed_p99_deg,
            r.speed_max_deg,
            r.delay_nominal,
            r.delay_measured
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flicker_ratio_is_one_for_the_truth_and_counts_jitter() {
        let truth: Vec<Vec<f64>> = (0..20).map(|t| vec![t as f64, 2.0 * t as f64]).collect();
        assert!((flicker_ratio(&truth, &truth) - 1.0).abs() < 1e-12);
        // ±2 alternating jitter on ramps of slope 1 and 2: of the 19 steps, 10 are slope − 4 and 9
        // slope + 4, so the total variation goes from 19·3 = 57 to (10·3 + 9·5) + (10·2 + 9·6) = 149.
        let jittery: Vec<Vec<f64>> = truth
            .iter()
            .enumerate()
            .map(|(t, v)| {
                let j = if t % 2 == 0 { 2.0 } else { -2.0 };
                v.iter().map(|x| x + j).collect()
            })
            .collect();
        let r = flicker_ratio(&jittery, &truth);
        assert!((r - 149.0 / 57.0).abs() < 1e-9, "{r}");
        // A lagging but exact copy of a step has the same total variation.
        let step: Vec<Vec<f64>> = (0..20)
            .map(|t| vec![if t < 10 { 0.0 } else { 1.0 }])
            .collect();
        let smooth: Vec<Vec<f64>> = (0..20)
            .map(|t| vec![((t as f64 - 10.0) / 4.0).clamp(0.0, 1.0)])
            .collect();
        assert!((flicker_ratio(&smooth, &step) - 1.0).abs() < 1e-12);
    }
}
