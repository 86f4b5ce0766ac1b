//! Stability where methods fail: hard cases × methods (`vemlight eval`, stability.md/.csv).
//!
//! Input: the deterministic hard cases of [`hard_cases`] (procedural 256×128 lat-long maps and
//! sequences). Output: per case and method, the diffuse error, the flicker ratio (sequences), the
//! largest jump of a light id between frames, and every violated invariant: finite output, energy
//! conserved (Σ irradiance = ∫ L dω of the sanitised map, 10⁻⁴ relative), every light inside the
//! domain, ids 0 … N−1 in order in every frame for the ordered methods. tests/stability.rs checks
//! the same invariants with its own assertions.

use super::scenes::{HARD_H, HARD_W, LatLongDirs, SunSky, dir_from_elev_azim, with_lamp};
use super::temporal::{Sequence, TemporalRow, run_sequence};
use crate::envmap::{EnvMap, Projection};
use crate::lights::error::IrradianceReference;
use crate::lights::{ExtractOptions, Extractor, Light, Method, total_irradiance};
use crate::mapping::Domain;

/// Light count of the hard cases, except the few-lights case.
pub const HARD_N: usize = 64;
/// Frames of each hard sequence.
pub const HARD_FRAMES: usize = 48;

/// What a hard case is made of.
pub enum CaseKind {
    /// One map, at these light counts.
    Static { map: EnvMap, counts: Vec<usize> },
    /// A sequence of maps, at [`HARD_N`] lights.
    Sequence { frames: Vec<EnvMap> },
}

pub struct HardCase {
    pub name: &'static str,
    pub description: &'static str,
    pub kind: CaseKind,
}

/// The hard cases of the stability table, deterministic.
pub fn hard_cases() -> Vec<HardCase> {
    let dirs = LatLongDirs::new(HARD_W, HARD_H);
    let sunny = SunSky {
        sun_sigma_deg: 1.5,
        sun_share: 0.8,
    };
    let sun_dir = dir_from_elev_azim(35.0, 40.0);
    let sun_map = sunny.render(&dirs, sun_dir);

    let overcast = dirs.map(|d| {
        if d.y >= 0.0 {
            // Near-uniform: ±3 % of texture in azimuth, 10 % brighter at the zenith.
            let az = d.x.atan2(-d.z);
            let v = 1.0 + 0.1 * d.y + 0.03 * (5.0 * az).sin();
            [v as f32 * 0.95, v as f32, v as f32 * 1.05]
        } else {
            [0.25, 0.24, 0.22]
        }
    });

    // Dim night: a faint sky, three small street lamps near the horizon, a dark ground.
    let night_base = dirs.map(|d| {
        if d.y >= 0.0 {
            [2e-5, 3e-5, 6e-5]
        } else {
            [4e-6; 3]
        }
    });
    let mut night = night_base.clone();
    for (k, az) in [20.0, 150.0, 260.0].iter().enumerate() {
        night = with_lamp(&night, dir_from_elev_azim(5.0 + k as f64, *az), 2.0, 0.3);
    }

    let mut hot = vec![[0.0f32; 3]; HARD_W * HARD_H];
    hot[30 * HARD_W + 77] = [1e4, 9e3, 8e3];
    let hot = EnvMap::from_pixels(HARD_W, HARD_H, hot, Projection::LatLong).expect("size");

    let black = EnvMap::from_pixels(
        HARD_W,
        HARD_H,
        vec![[0.0; 3]; HARD_W * HARD_H],
        Projection::LatLong,
    )
    .expect("size");

    // NaN, ±inf and negative pixels scattered over the sunny map (clamped to 0 on load).
    let mut bad = sun_map.pixels.clone();
    for (k, p) in bad.iter_mut().enumerate() {
        if k % 97 == 0 {
            *p = [f32::NAN, 1.0, 1.0];
        } else if k % 89 == 0 {
            *p = [-5.0, -0.1, 2.0];
        } else if k % 1009 == 0 {
            *p = [f32::INFINITY, f32::NEG_INFINITY, 0.5];
        }
    }
    let bad = EnvMap::from_pixels(HARD_W, HARD_H, bad, Projection::LatLong).expect("size");

    // The sun crossing the lat-long seam (φ = ±180°, toward +Z) at 20° elevation, 0.5°/frame.
    let seam: Vec<EnvMap> = (0..HARD_FRAMES)
        .map(|t| {
            let az = 180.0 + (t as f64 - HARD_FRAMES as f64 / 2.0) * 0.5;
            sunny.render(&dirs, dir_from_elev_azim(20.0, az))
        })
        .collect();
    // The sun passing the zenith: elevation 78° → 90° → 78° on the other side, 0.5°/frame.
    let zenith: Vec<EnvMap> = (0..HARD_FRAMES)
        .map(|t| {
            let a = (t as f64 - HARD_FRAMES as f64 / 2.0) * 0.5;
            let (elev, az) = if a <= 0.0 {
                (90.0 + a, 90.0)
            } else {
                (90.0 - a, 270.0)
            };
            sunny.render(&dirs, dir_from_elev_azim(elev, az))
        })
        .collect();
    // A lamp holding 40 % of the energy, off for a third of the frames, on, then off again.
    let lamp_on = with_lamp(&overcast, dir_from_elev_azim(15.0, -60.0), 2.0, 0.4);
    let switch: Vec<EnvMap> = (0..HARD_FRAMES)
        .map(|t| {
            if (HARD_FRAMES / 3..2 * HARD_FRAMES / 3).contains(&t) {
                lamp_on.clone()
            } else {
                overcast.clone()
            }
        })
        .collect();

    let st = |map: EnvMap| CaseKind::Static {
        map,
        counts: vec![HARD_N],
    };
    vec![
        HardCase {
            name: "sun-80%",
            description: "a Gaussian sun (σ = 1.5°) holding 80 % of the energy",
            kind: st(sun_map.clone()),
        },
        HardCase {
            name: "overcast",
            description: "a near-uniform overcast sky (±3 % texture)",
            kind: st(overcast),
        },
        HardCase {
            name: "dim-night",
            description: "a night sky of 3·10⁻⁵ with three faint lamps",
            kind: st(night),
        },
        HardCase {
            name: "hot-pixel",
            description: "a black map with one pixel of 10⁴",
            kind: st(hot),
        },
        HardCase {
            name: "all-black",
            description: "every pixel 0",
            kind: st(black),
        },
        HardCase {
            name: "nan-negative",
            description: "the sunny map with 1 % NaN, 1 % negative and some ±inf pixels",
            kind: st(bad),
        },
        HardCase {
            name: "n-1-4",
            description: "the sunny map with N = 1, 2, 3, 4 (error column: N = 4)",
            kind: CaseKind::Static {
                map: sun_map,
                counts: vec![1, 2, 3, 4],
            },
        },
        HardCase {
            name: "seam",
            description: "the sun crossing the lat-long seam, 0.5°/frame",
            kind: CaseKind::Sequence { frames: seam },
        },
        HardCase {
            name: "zenith",
            description: "the sun passing the zenith, 0.5°/frame",
            kind: CaseKind::Sequence { frames: zenith },
        },
        HardCase {
            name: "switch",
            description: "a lamp with 40 % of the energy switched on, then off",
            kind: CaseKind::Sequence { frames: switch },
        },
    ]
}

/// Every invariant `lights` violates for a map, as readable strings (empty: all hold).
pub fn violations(
    map: &EnvMap,
    domain: Domain,
    method: Method,
    n: usize,
    lights: &[Light],
) -> Vec<String> {
    let mut v = Vec::new();
    if lights.iter().any(|l| {
        !l.to_light
            .iter()
            .chain(&l.irradiance)
            .all(|c| c.is_finite())
    }) {
        v.push("non-finite light".to_string());
    }
    let truth = map.integral(domain);
    let sum = total_irradiance(lights);
    for c in 0..3 {
        let tol = 1e-4 * truth[c].abs() + 1e-12;
        if (sum[c] - truth[c]).abs() > tol || !sum[c].is_finite() {
            v.push(format!("energy {:.6e} vs {:.6e}", sum[c], truth[c]));
            break;
        }
    }
    if lights.iter().any(|l| l.irradiance.iter().any(|&c| c < 0.0)) {
        v.push("negative irradiance".to_string());
    }
    if lights.iter().any(|l| {
        let d = l.dir();
        (d.length() - 1.0).abs() > 1e-4 || (domain == Domain::Upper && d.y < -1e-5)
    }) {
        v.push("light outside the domain".to_string());
    }
    if method.ids_are_stable()
        && (lights.len() != n || lights.iter().enumerate().any(|(k, l)| l.id != k as u32))
    {
        v.push(format!("ids not 0..{n}"));
    }
    v
}

/// One cell of the stability table.
#[derive(Clone, Debug)]
pub struct StabilityRow {
    pub case: &'static str,
    pub method: Method,
    pub lights: usize,
    /// Diffuse relative RMS (sphere; mean over frames for sequences).
    pub error: f64,
    /// Flicker ratio without filter (sequences only).
    pub flicker: Option<f64>,
    /// Largest jump of a light id between frames, degrees (sequences only).
    pub max_jump_deg: Option<f64>,
    /// Violated invariants over both domains and every count/frame (deduplicated).
    pub violations: Vec<String>,
}

/// Runs every method on every hard case; `tick` after each case.
pub fn run(cases: &[HardCase], mut tick: impl FnMut()) -> Vec<StabilityRow> {
    let mut rows = Vec::new();
    for case in cases {
        let mut temporal: Vec<TemporalRow> = Vec::new();
        if let CaseKind::Sequence { frames } = &case.kind {
            let mut seq = Sequence {
                name: case.name.to_string(),
                description: case.description.to_string(),
                frames: frames.len(),
                render: Box::new(|t| frames[t].clone()),
                turn_per_frame: None,
            };
            temporal = run_sequence(&mut seq, HARD_N, Domain::Sphere, false, || {});
        }
        let (maps, counts): (Vec<&EnvMap>, Vec<usize>) = match &case.kind {
            CaseKind::Static { map, counts } => (vec![map], counts.clone()),
            CaseKind::Sequence { frames } => (frames.iter().collect(), vec![HARD_N]),
        };
        let refs: Vec<IrradianceReference> = maps
            .iter()
            .map(|m| IrradianceReference::from_map(m, Domain::Sphere))
            .collect();
        for method in Method::STREAMING {
            let mut ex = Extractor::new();
            let mut viol: Vec<String> = Vec::new();
            let mut error = 0.0;
            for domain in [Domain::Sphere, Domain::Upper] {
                for &n in &counts {
                    let mut errs = Vec::new();
                    for (map, reference) in maps.iter().zip(&refs) {
                        let opts = ExtractOptions {
                            lights: n,
                            domain,
                            method,
                            side: None,
                        };
                        let out = ex.extract(map, &opts);
                        for s in violations(map, domain, method, n, &out.lights) {
                            let s = format!("{s} ({}, N = {n})", domain.name());
                            if !viol.contains(&s) {
                                viol.push(s);
                            }
                        }
                        if domain == Domain::Sphere && Some(&n) == counts.last() {
                            errs.push(reference.error(&out.lights).rel_rms);
                        }
                    }
                    if !errs.is_empty() {
                        error = errs.iter().sum::<f64>() / errs.len() as f64;
                    }
                }
            }
            let t = temporal
                .iter()
                .find(|r| r.method == method.name() && r.filter == "none");
            rows.push(StabilityRow {
                case: case.name,
                method,
                lights: *counts.last().expect("a count"),
                error,
                flicker: t.map(|r| r.flicker),
                max_jump_deg: t.map(|r| r.speed_max_deg),
                violations: viol,
            });
        }
        tick();
    }
    rows
}

/// The stability table as markdown: cases as rows, methods as columns.
pub fn to_markdown(cases: &[HardCase], rows: &[StabilityRow]) -> String {
    let mut s = String::from("| case | ");
    s += &Method::STREAMING.map(|m| m.name()).join(" | ");
    s += " |\n|---|";
    s += &"---|".repeat(Method::STREAMING.len());
    s += "\n";
    for case in cases {
        s += &format!("| **{}**: {} |", case.name, case.description);
        for m in Method::STREAMING {
            let Some(r) = rows.iter().find(|r| r.case == case.name && r.method == m) else {
                s += " |";
                continue;
            };
            let mut cell = format!(" {}", fmt_pct(r.error));
            if let Some(f) = r.flicker {
                cell += &format!(" · flicker {f:.2}");
            }
            if let Some(j) = r.max_jump_deg {
                cell += &format!(" · jump {j:.1}°");
            }
            cell += if r.violations.is_empty() {
                " · ok"
            } else {
                " · **FAIL**: "
            };
            cell += &r.violations.join("; ");
            s += &cell;
            s += " |";
        }
        s += "\n";
    }
    s
}

/// stability.csv.
pub fn to_csv(rows: &[StabilityRow]) -> String {
    let mut s =
        String::from("case,method,lights,diffuse_rel_rms,flicker_ratio,max_jump_deg,violations\n");
    let opt = |v: Option<f64>| v.map(|v| format!("{v:.4}")).unwrap_or_default();
    for r in rows {
        s += &format!(
            "{},{},{},{:.6},{},{},\"{}\"\n",
            r.case,
            r.method.name(),
            r.lights,
            r.error,
            opt(r.flicker),
            opt(r.max_jump_deg),
            r.violations.join("; ")
        );
    }
    s
}

/// A relative error as a percentage with sensible digits.
pub fn fmt_pct(e: f64) -> String {
    if !e.is_finite() {
        return "∞".to_string();
    }
    let p = e * 100.0;
    if p >= 10.0 {
        format!("{p:.0} %")
    } else if p >= 1.0 {
        format!("{p:.1} %")
    } else {
        format!("{p:.2} %")
    }
}
