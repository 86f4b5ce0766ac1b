//! Per-map tables with the worst map named, and the placement frontier of the default method
//! (`vemlight eval`: per_map.md, frontier.csv / .md / .svg).
//!
//! The project is judged by its worst map, not the median: every figure here is per map, each
//! method's diffuse error is given as a ratio to converged k-means (the floor, ALGORITHMS.md §10),
//! and the shadowed error (§9) beside median cut's.

use super::accuracy::{AccuracyRow, SHADOW_COUNTS, Truth};
use super::stability::fmt_pct;
use crate::envmap::EnvMap;
use crate::lights::{ExtractOptions, Extractor, Method, Placement};
use crate::mapping::Domain;

/// The row of one (map, method, N) in `domain`.
fn row_in<'a>(
    rows: &'a [AccuracyRow],
    domain: Domain,
    map: &str,
    method: Method,
    n: usize,
) -> Option<&'a AccuracyRow> {
    rows.iter().find(|r| {
        r.domain == domain && r.map == map && r.method == method.name() && r.lights == Some(n)
    })
}

fn maps_of(rows: &[AccuracyRow]) -> Vec<String> {
    let mut maps: Vec<String> = Vec::new();
    for r in rows {
        if !maps.contains(&r.map) {
            maps.push(r.map.clone());
        }
    }
    maps
}

/// The worst (largest) value of `f` over maps, with the map's name.
fn worst(maps: &[String], f: impl Fn(&str) -> Option<f64>) -> Option<(f64, &str)> {
    maps.iter()
        .filter_map(|m| f(m).filter(|v| v.is_finite()).map(|v| (v, m.as_str())))
        .max_by(|a, b| a.0.total_cmp(&b.0))
}

/// The median (NaN for none).
fn median(mut v: Vec<f64>) -> f64 {
    super::speed::median(&mut v)
}

/// per_map.md: one table per N (16, 64, 256 where measured), then the targets per N, in
/// `domain`: the whole sphere (a lat-long map's), or the upper hemisphere, the domain of a sky
/// camera's fisheye (`vemlight eval --upper`), whose truth, k-means floor and median cut see
/// only the light from above the horizon.
pub fn markdown(rows: &[AccuracyRow], domain: Domain) -> String {
    let maps = maps_of(rows);
    let row = |rows, map: &str, method, n| row_in(rows, domain, map, method, n);
    let within = match domain {
        Domain::Sphere => "whole sphere",
        Domain::Upper => "upper hemisphere",
    };
    let ratio_methods = [
        Method::Voronoi,
        Method::MedianCut,
        Method::Vmlps,
        Method::InverseCdf,
        Method::Paper,
    ];
    let shadow_methods = [
        Method::Voronoi,
        Method::MedianCut,
        Method::Vmlps,
        Method::KMeans,
    ];
    let ratio = |m: &str, method: Method, n: usize| {
        let k = row(rows, m, Method::KMeans, n)?.diffuse.rel_rms;
        let v = row(rows, m, method, n)?.diffuse.rel_rms;
        Some(super::accuracy::ratio(v, k))
    };
    let shadowed = |m: &str, method: Method, n: usize| row(rows, m, method, n)?.shadowed_mean();
    let mut s = String::new();
    for n in [16usize, 64, 256] {
        if row(rows, &maps[0], Method::Voronoi, n).is_none() {
            continue;
        }
        s += &format!(
            "\n**N = {n}**, {within}. Diffuse: ratio to converged k-means (the floor; its own error in the k-means column). Shadowed: relative RMS on the ground of the three occluder scenes (mean over scenes). Energy: lights that carry energy, default method.\n\n| map | {} | k-means | {} | energy |\n|---|{}---|{}---|\n",
            ratio_methods.map(|m| format!("{} ×", m.name())).join(" | "),
            shadow_methods
                .map(|m| format!("{} shadowed", m.name()))
                .join(" | "),
            "---|".repeat(ratio_methods.len()),
            "---|".repeat(shadow_methods.len()),
        );
        let cell = |v: Option<f64>| v.map(|v| format!("{v:.2}")).unwrap_or_else(|| "—".into());
        let pct = |v: Option<f64>| v.map(fmt_pct).unwrap_or_else(|| "—".into());
        for m in &maps {
            s += &format!(
                "| {m} | {} | {} | {} | {} |\n",
                ratio_methods.map(|x| cell(ratio(m, x, n))).join(" | "),
                pct(row(rows, m, Method::KMeans, n).map(|r| r.diffuse.rel_rms)),
                shadow_methods.map(|x| pct(shadowed(m, x, n))).join(" | "),
                row(rows, m, Method::Voronoi, n)
                    .map(|r| format!("{} / {n}", r.alive))
                    .unwrap_or_default(),
            );
        }
        let named = |w: Option<(f64, &str)>, f: &dyn Fn(f64) -> String| {
            w.map(|(v, m)| format!("**{}** {m}", f(v)))
                .unwrap_or_else(|| "—".into())
        };
        s += &format!(
            "| **worst** | {} | {} | {} | {} |\n",
            ratio_methods
                .map(|x| named(worst(&maps, |m| ratio(m, x, n)), &|v| format!("{v:.2}")))
                .join(" | "),
            named(
                worst(&maps, |m| row(rows, m, Method::KMeans, n)
                    .map(|r| r.diffuse.rel_rms)),
                &fmt_pct
            ),
            shadow_methods
                .map(|x| named(worst(&maps, |m| shadowed(m, x, n)), &fmt_pct))
                .join(" | "),
            maps.iter()
                .filter_map(|m| row(rows, m, Method::Voronoi, n).map(|r| (r.alive, m)))
                .min()
                .map(|(a, m)| format!("**{a}** {m}"))
                .unwrap_or_default(),
        );
    }

    s += &format!(
        "\n**Targets per N**, default method, every map ({within}): diffuse ≤ 1.25 × k-means, shadowed ≤ median cut's, every light with energy.\n\n| N | worst diffuse / k-means | median | maps with shadowed > median cut's (worst ratio) | lights with energy, fewest | met? |\n|---|---|---|---|---|---|\n"
    );
    for n in SHADOW_COUNTS {
        if row(rows, &maps[0], Method::Voronoi, n).is_none() {
            continue;
        }
        let w = worst(&maps, |m| ratio(m, Method::Voronoi, n));
        let med = median(
            maps.iter()
                .filter_map(|m| ratio(m, Method::Voronoi, n))
                .collect(),
        );
        let shadow_ratio = |m: &str| {
            let v = shadowed(m, Method::Voronoi, n)?;
            let c = shadowed(m, Method::MedianCut, n)?;
            Some(if c > 0.0 { v / c } else { 1.0 })
        };
        let over: Vec<&String> = maps
            .iter()
            .filter(|m| shadow_ratio(m).is_some_and(|r| r > 1.0))
            .collect();
        let ws = worst(&maps, shadow_ratio);
        let fewest = maps
            .iter()
            .filter_map(|m| row(rows, m, Method::Voronoi, n).map(|r| (r.alive, m)))
            .min();
        let met = w.is_some_and(|(v, _)| v <= 1.25)
            && over.is_empty()
            && fewest.is_some_and(|(a, _)| a == n);
        s += &format!(
            "| {n} | {} | {med:.2} | {} of {} ({}) | {} | {} |\n",
            w.map(|(v, m)| format!("{v:.2} ({m})")).unwrap_or_default(),
            over.len(),
            maps.len(),
            ws.map(|(v, m)| format!("{v:.2}, {m}")).unwrap_or_default(),
            fewest
                .map(|(a, m)| format!("{a} ({m})"))
                .unwrap_or_default(),
            if met { "yes" } else { "**no**" },
        );
    }
    s
}

/// One point of the frontier: a placement on one map at one N.
#[derive(Clone, Debug)]
pub struct FrontierRow {
    pub placement: Placement,
    pub map: String,
    pub lights: usize,
    pub diffuse: f64,
    pub shadowed: f64,
    /// Diffuse over converged k-means' on the same map and N.
    pub diffuse_ratio: f64,
    /// Shadowed over median cut's on the same map and N.
    pub shadowed_ratio: f64,
}

/// The placements swept: density exponents × caps (0: no cap) × uniform shares.
pub fn placements() -> Vec<Placement> {
    let mut out = Vec::new();
    for exponent in [0.5f32, 0.625, 0.75, 0.875, 1.0] {
        for (max_seeds_per_texel, uniform_share) in [(0.0f32, 0.0f32), (0.5, 0.0), (0.5, 0.1)] {
            out.push(Placement {
                exponent,
                max_seeds_per_texel,
                uniform_share,
            });
        }
    }
    out
}

/// Every placement of [`placements`] on every map (sphere) at each of `counts`, against the
/// k-means and median-cut rows of the accuracy part. `truths` are the maps' sphere truths, in
/// the order of `maps`.
pub fn frontier(
    maps: &[(String, EnvMap)],
    truths: &[Truth],
    rows: &[AccuracyRow],
    counts: &[usize],
) -> Vec<FrontierRow> {
    let mut out = Vec::new();
    let mut ex = Extractor::new();
    // Each row is its placement alone: the default's second start (Y^½) would mix one in.
    ex.set_other_starts(false);
    for placement in placements() {
        ex.set_placement(placement);
        for ((name, map), truth) in maps.iter().zip(truths) {
            for &n in counts {
                let (Some(k), Some(mc)) = (
                    row_in(rows, Domain::Sphere, name, Method::KMeans, n),
                    row_in(rows, Domain::Sphere, name, Method::MedianCut, n),
                ) else {
                    continue;
                };
                let opts = ExtractOptions {
                    lights: n,
                    domain: Domain::Sphere,
                    method: Method::Voronoi,
                    side: None,
                };
                let lights = ex.extract(map, &opts).lights;
                let diffuse = truth.diffuse.error(&lights).rel_rms;
                let shadowed = truth.shadowed_mean(&lights);
                let kd = k.diffuse.rel_rms;
                let ms = mc.shadowed_mean().unwrap_or(f64::NAN);
                out.push(FrontierRow {
                    placement,
                    map: name.clone(),
                    lights: n,
                    diffuse,
                    shadowed,
                    diffuse_ratio: if kd > 0.0 { diffuse / kd } else { 1.0 },
                    shadowed_ratio: if ms > 0.0 { shadowed / ms } else { 1.0 },
                });
            }
        }
    }
    out
}

pub fn frontier_csv(rows: &[FrontierRow]) -> String {
    let mut s = String::from(
        "exponent,max_seeds_per_texel,uniform_share,map,lights,diffuse_rel_rms,shadowed_rel_rms,diffuse_over_kmeans,shadowed_over_median_cut\n",
    );
    for r in rows {
        s += &format!(
            "{},{},{},{},{},{:.6},{:.6},{:.4},{:.4}\n",
            r.placement.exponent,
            r.placement.max_seeds_per_texel,
            r.placement.uniform_share,
            r.map,
            r.lights,
            r.diffuse,
            r.shadowed,
            r.diffuse_ratio,
            r.shadowed_ratio
        );
    }
    s
}

/// Worst-map summary of one placement over all its rows: (worst diffuse ratio, its map and N,
/// worst shadowed ratio, its map and N).
pub fn worst_of(rows: &[&FrontierRow]) -> ((f64, String), (f64, String)) {
    let label = |r: &FrontierRow| format!("{} N={}", r.map, r.lights);
    let d = rows
        .iter()
        .max_by(|a, b| a.diffuse_ratio.total_cmp(&b.diffuse_ratio))
        .map(|r| (r.diffuse_ratio, label(r)))
        .unwrap_or((f64::NAN, String::new()));
    let s = rows
        .iter()
        .max_by(|a, b| a.shadowed_ratio.total_cmp(&b.shadowed_ratio))
        .map(|r| (r.shadowed_ratio, label(r)))
        .unwrap_or((f64::NAN, String::new()));
    (d, s)
}

/// The rows of each placement, in sweep order.
pub fn by_placement(rows: &[FrontierRow]) -> Vec<(Placement, Vec<&FrontierRow>)> {
    let mut out: Vec<(Placement, Vec<&FrontierRow>)> = Vec::new();
    for r in rows {
        match out.iter_mut().find(|(p, _)| *p == r.placement) {
            Some((_, v)) => v.push(r),
            None => out.push((r.placement, vec![r])),
        }
    }
    out
}

pub fn frontier_markdown(rows: &[FrontierRow]) -> String {
    let mut s = String::from(
        "Default method with one start (the default takes four up to 32 lights, Y^⅜ to Y^¾, three from 33 to 64, Y^½ to Y¹, and three from 65 to 192, Y^⅝ to Y^⅞: ALGORITHMS.md §4.2), whole sphere, every map and N of the sweep; worst map first, median after. Diffuse ÷ k-means (target ≤ 1.25), shadowed ÷ median cut (target ≤ 1).\n\n| exponent | cap (seeds/texel) | uniform share | worst diffuse ÷ k-means | median | worst shadowed ÷ median cut | median |\n|---|---|---|---|---|---|---|\n",
    );
    for (p, rs) in by_placement(rows) {
        let ((wd, wdm), (ws, wsm)) = worst_of(&rs);
        let md = median(rs.iter().map(|r| r.diffuse_ratio).collect());
        let ms = median(rs.iter().map(|r| r.shadowed_ratio).collect());
        // The counts of the sweep at which this is a single map's placement.
        let mut counts: Vec<usize> = rs
            .iter()
            .map(|r| r.lights)
            .filter(|&n| Placement::for_lights(n) == p)
            .collect();
        counts.sort_unstable();
        counts.dedup();
        let mark = if counts.is_empty() {
            String::new()
        } else {
            let counts: Vec<String> = counts.iter().map(|n| n.to_string()).collect();
            format!(" (default at N = {})", counts.join(", "))
        };
        s += &format!(
            "| {}{mark} | {} | {} | {wd:.2} ({wdm}) | {md:.2} | {ws:.2} ({wsm}) | {ms:.2} |\n",
            p.exponent,
            if p.max_seeds_per_texel > 0.0 {
                format!("{}", p.max_seeds_per_texel)
            } else {
                "none".into()
            },
            p.uniform_share,
        );
    }
    s
}
