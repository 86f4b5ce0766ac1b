//! A client's shadow budget, measured (`vemlight eval`, budget.md): for K = 1, 2, 4, 8, 16, the
//! diffuse and shadowed error (ALGORITHMS.md §8, §9) of three ways to light a scene with K
//! shadow maps, on every map:
//!
//! - **K lights**: a set of K lights, every one shadowed.
//! - **K + SH**: the stream's default set of [`BUDGET_SET`] lights with K marked shadowed
//!   ([`crate::lights::budget::mark`]) and the rest as the remainder SH (`sh9_unshadowed`),
//!   shaded without visibility.
//! - **SH alone**: the map's L2 SH, no lights, no shadows.

use super::accuracy::Truth;
use super::speed::median;
use crate::envmap::{EnvMap, luminance64};
use crate::lights::budget::{mark, remainder_sh};
use crate::lights::error::relative_error;
use crate::lights::{Extractor, FrameRequest, Light, Method, sh};
use crate::mapping::Domain;
use glam::DVec3;

/// The shadow budgets measured.
pub const BUDGETS: [usize; 5] = [1, 2, 4, 8, 16];

/// The set the K + SH variant marks its K lights in: the daemon's default light count.
pub const BUDGET_SET: usize = 64;

/// The three variants, in table order.
pub const VARIANTS: [&str; 3] = ["K lights", "K + SH", "SH alone"];

/// One map, one budget, one variant.
#[derive(Clone, Debug)]
pub struct BudgetRow {
    pub map: String,
    pub k: usize,
    /// One of [`VARIANTS`].
    pub variant: &'static str,
    pub diffuse: f64,
    /// Mean over the shadow scenes of the relative RMS.
    pub shadowed: f64,
}

/// Irradiance (luminance) at normal `n` from 27 radiance SH coefficients.
fn sh_irradiance(coeffs: &[f32], n: DVec3) -> f64 {
    let mut c = [0.0f64; 27];
    for (o, &v) in c.iter_mut().zip(coeffs) {
        *o = v as f64;
    }
    luminance64(sh::irradiance(&c, n))
}

/// Diffuse and shadowed error of `lights` (all shadowed) plus an unshadowed SH term.
fn errors(truth: &Truth, lights: &[Light], ambient: Option<&[f32]>) -> (f64, f64) {
    let normals = truth.diffuse.normals();
    let mut estimate = truth.diffuse.light_irradiance(lights);
    if let Some(c) = ambient {
        for (e, &n) in estimate.iter_mut().zip(normals) {
            *e += sh_irradiance(c, n);
        }
    }
    let diffuse = truth.diffuse.error_of(&estimate).rel_rms;
    // The ground's normal is +Y: the SH term is the same at every probe, with no visibility.
    let ground = ambient.map_or(0.0, |c| sh_irradiance(c, DVec3::Y));
    let per_scene: Vec<f64> = truth
        .shadow
        .iter()
        .map(|(scene, reference)| {
            let lit: Vec<f64> = super::shadowed::lights_irradiance(scene, lights)
                .into_iter()
                .map(|e| e + ground)
                .collect();
            relative_error(&lit, reference.truth()).rel_rms
        })
        .collect();
    let shadowed = per_scene.iter().sum::<f64>() / per_scene.len().max(1) as f64;
    (diffuse, shadowed)
}

/// Every budget and variant on one map (sphere domain).
pub fn evaluate_map(name: &str, map: &EnvMap, truth: &Truth) -> Vec<BudgetRow> {
    let mut ex = Extractor::new();
    let image = ex.resample(map, Domain::Sphere, None);
    fn request(counts: &[usize]) -> FrameRequest<'_> {
        FrameRequest {
            method: Method::Voronoi,
            counts,
            sh9: true,
        }
    }
    let mut rows = Vec::new();
    let set = ex.extract_frame(map, &image, &request(&[BUDGET_SET]));
    let sh9 = set.sh9.expect("asked for");
    let full: Vec<Light> = set.extractions[0]
        .lights
        .iter()
        .copied()
        .filter(Light::carries_energy)
        .collect();
    let (sh_diffuse, sh_shadowed) = errors(truth, &[], Some(&sh9));
    for k in BUDGETS {
        let alone = ex.extract_frame(map, &image, &request(&[k]));
        let lights: Vec<Light> = alone.extractions[0].lights.clone();
        let (d, s) = errors(truth, &lights, None);
        rows.push(BudgetRow {
            map: name.into(),
            k,
            variant: VARIANTS[0],
            diffuse: d,
            shadowed: s,
        });
        let mut marked = full.clone();
        mark(&mut marked, k, &[]);
        let rest = remainder_sh(&sh9, &marked);
        let shadowed: Vec<Light> = marked
            .iter()
            .copied()
            .filter(|l| l.shadowed == Some(true))
            .collect();
        let (d, s) = errors(truth, &shadowed, Some(&rest));
        rows.push(BudgetRow {
            map: name.into(),
            k,
            variant: VARIANTS[1],
            diffuse: d,
            shadowed: s,
        });
        rows.push(BudgetRow {
            map: name.into(),
            k,
            variant: VARIANTS[2],
            diffuse: sh_diffuse,
            shadowed: sh_shadowed,
        });
    }
    rows
}

/// The table: per K and variant, the median over maps and the worst map, diffuse and shadowed.
pub fn markdown(rows: &[BudgetRow]) -> String {
    let mut s = String::from(
        "Relative RMS, sphere domain; median over maps (worst map). K + SH marks K of the default \
         set's 64 lights and gives the rest as the remainder SH, drawn without shadows.\n\n\
         | K | variant | diffuse | shadowed |\n|---|---|---|---|\n",
    );
    let pct = |v: f64| format!("{:.2} %", 100.0 * v);
    for k in BUDGETS {
        for variant in VARIANTS {
            let these: Vec<&BudgetRow> = rows
                .iter()
                .filter(|r| r.k == k && r.variant == variant)
                .collect();
            if these.is_empty() {
                continue;
            }
            let cell = |f: &dyn Fn(&BudgetRow) -> f64| {
                let mut values: Vec<f64> = these.iter().map(|r| f(r)).collect();
                let worst = these
                    .iter()
                    .max_by(|a, b| f(a).total_cmp(&f(b)))
                    .expect("non-empty");
                format!(
                    "{} ({}, {})",
                    pct(median(&mut values)),
                    pct(f(worst)),
                    worst.map
                )
            };
            s.push_str(&format!(
                "| {k} | {variant} | {} | {} |\n",
                cell(&|r| r.diffuse),
                cell(&|r| r.shadowed)
            ));
        }
    }
    s
}

/// The rows as CSV.
pub fn to_csv(rows: &[BudgetRow]) -> String {
    let mut s = String::from("map,k,variant,diffuse,shadowed\n");
    for r in rows {
        s.push_str(&format!(
            "{},{},{},{:.6},{:.6}\n",
            r.map, r.k, r.variant, r.diffuse, r.shadowed
        ));
    }
    s
}

/// The error targets whose adaptive count is measured over time.
pub const ADAPTIVE_TARGETS: [f64; 2] = [0.01, 0.02];

/// The most lights of the measured adaptive streams: the daemon's default count.
pub const ADAPTIVE_MAX: usize = 64;

/// How an adaptive stream's light count behaved over one sequence.
#[derive(Clone, Debug)]
pub struct AdaptiveRow {
    pub sequence: String,
    pub target: f64,
    pub frames: usize,
    /// Count changes after the first frame.
    pub changes: usize,
    /// Changes per minute at `fps`.
    pub per_minute: f64,
    pub mean_count: f64,
    /// Share of frames whose served count met the target.
    pub met: f64,
}

/// Runs an adaptive stream ([`AdaptiveCount`](crate::lights::budget::AdaptiveCount), as the
/// daemon does, video mode on) over `frames` frames of `render` at `fps`.
pub fn adaptive_run(
    sequence: &str,
    frames: usize,
    fps: f64,
    target: f64,
    mut render: impl FnMut(usize) -> EnvMap,
) -> AdaptiveRow {
    use crate::lights::budget::AdaptiveCount;
    use crate::lights::error::IrradianceReference;
    let mut ex = Extractor::new();
    ex.set_video(true);
    let mut adaptive = AdaptiveCount::new(ADAPTIVE_MAX, target);
    let (mut changes, mut count_sum, mut met) = (0usize, 0usize, 0usize);
    for k in 0..frames {
        let map = render(k);
        let image = ex.resample(&map, Domain::Sphere, None);
        let counts = adaptive.counts_needed();
        let frame = ex.extract_frame(
            &map,
            &image,
            &FrameRequest {
                method: Method::Voronoi,
                counts: &counts,
                sh9: false,
            },
        );
        let reference = IrradianceReference::from_domain_image(&image);
        let before = adaptive.count();
        let (served, error) = adaptive.update(|n| {
            counts
                .iter()
                .position(|&c| c == n)
                .map(|i| reference.error(&frame.extractions[i].lights).rel_rms)
        });
        if before != 0 && adaptive.count() != before {
            changes += 1;
        }
        count_sum += served;
        if error.is_some_and(|e| e <= target) {
            met += 1;
        }
    }
    let minutes = frames as f64 / fps / 60.0;
    AdaptiveRow {
        sequence: sequence.into(),
        target,
        frames,
        changes,
        per_minute: changes as f64 / minutes,
        mean_count: count_sum as f64 / frames as f64,
        met: met as f64 / frames as f64,
    }
}

/// The adaptive table.
pub fn adaptive_markdown(rows: &[AdaptiveRow]) -> String {
    let mut s = format!(
        "At most {ADAPTIVE_MAX} lights, 30 frames/s; a change is one step of the count (up at once, \
         down after 30 frames at 0.8 E).\n\n\
         | sequence | E | frames | count changes | per minute | mean count | frames meeting E |\n\
         |---|---|---|---|---|---|---|\n"
    );
    for r in rows {
        s.push_str(&format!(
            "| {} | {:.0} % | {} | {} | {:.1} | {:.1} | {:.0} % |\n",
            r.sequence,
            100.0 * r.target,
            r.frames,
            r.changes,
            r.per_minute,
            r.mean_count,
            100.0 * r.met
        ));
    }
    s
}
