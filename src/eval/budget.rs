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
