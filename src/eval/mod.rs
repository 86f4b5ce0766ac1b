//! Measurement: per-frame speed of each method, accuracy × speed charts, temporal stability, and
//! the hard cases where methods fail (`vemlight bench`, `vemlight eval`).
//!
//! Input: HDR maps (default tests/data). Output: docs/eval/ (CSV, SVG, markdown tables) and the
//! generated sections of docs/EVALUATION.md, between `<!-- BEGIN name -->` / `<!-- END name -->`
//! markers. Speed figures are medians, because these machines are noisy.

pub mod accuracy;
pub mod between;
pub mod budget;
pub mod charts;
pub mod per_map;
pub mod scenes;
pub mod shadowed;
pub mod speed;
pub mod stability;
pub mod temporal;

use crate::envmap::{DEFAULT_MAX_PIXELS, EnvMap};
use crate::mapping::Domain;
use crate::sky::{SyntheticConfig, SyntheticSky};
use accuracy::{AccuracyRow, COUNTS, SH_NAME, Truth, spread};
use anyhow::Context;
use glam::DQuat;
use indicatif::{ProgressBar, ProgressStyle};
use scenes::{LatLongDirs, dir_from_elev_azim, scaled, with_lamp};
use stability::fmt_pct;
use std::path::{Path, PathBuf};
use std::time::Instant;
use temporal::{Sequence, TemporalRow, run_sequence};

/// What `vemlight eval` runs.
#[derive(Clone, Debug)]
pub struct EvalOptions {
    /// Directory of .exr/.hdr maps (lat-long).
    pub maps: PathBuf,
    /// Output directory for CSV/SVG/markdown.
    pub out: PathBuf,
    /// The document whose generated sections are rewritten (skipped if it does not exist).
    pub doc: Option<PathBuf>,
    /// Fewer counts, repetitions and frames: a smoke run, not the published figures.
    pub quick: bool,
    /// Also evaluate the upper hemisphere.
    pub upper: bool,
}

/// The map of the rotation, exposure and switch sequences (a sun close to the horizon: the case
/// where flicker is most visible).
pub const SEQUENCE_MAP: &str = "sunrise.exr";
/// Light count of the temporal part (the prototype's figures are at 64).
pub const TEMPORAL_N: usize = 64;
/// Rotation speed of the rotation sequences, degrees per frame.
pub const ROTATION_DEG_PER_FRAME: f64 = 0.25;

struct Plan {
    counts: Vec<usize>,
    /// Counts between the powers of two ([`between`]).
    between: Vec<usize>,
    reps: usize,
    frames: usize,
}

/// Runs the whole evaluation and writes its files; returns a short summary for the terminal.
pub fn run(opts: &EvalOptions) -> anyhow::Result<String> {
    let started = Instant::now();
    let plan = if opts.quick {
        Plan {
            counts: vec![16, 64, 256],
            between: between::QUICK_BETWEEN_COUNTS.to_vec(),
            reps: 1,
            frames: 16,
        }
    } else {
        Plan {
            counts: COUNTS.to_vec(),
            between: between::BETWEEN_COUNTS.to_vec(),
            reps: 5,
            frames: 96,
        }
    };
    let mut maps = load_maps(&opts.maps)?;
    anyhow::ensure!(
        !maps.is_empty(),
        "no .exr/.hdr maps in {}",
        opts.maps.display()
    );
    maps.extend(scenes::hard_skies(if opts.quick { 512 } else { 1024 }));
    std::fs::create_dir_all(&opts.out)
        .with_context(|| format!("cannot create {}", opts.out.display()))?;
    let domains: Vec<Domain> = if opts.upper {
        vec![Domain::Sphere, Domain::Upper]
    } else {
        vec![Domain::Sphere]
    };

    let methods = crate::lights::Method::ALL.len() + 1;
    let sequences = 3 + 2 * maps.len();
    let hard = stability::hard_cases();
    let total =
        (maps.len() * (domains.len() * methods + 1) + sequences * plan.frames + hard.len()) as u64;
    let bar = ProgressBar::new(total);
    bar.set_style(
        ProgressStyle::with_template("{elapsed_precise} [{bar:40}] {pos}/{len} {msg}")
            .expect("valid template")
            .progress_chars("=> "),
    );

    // 1. Accuracy × speed.
    let mut rows: Vec<AccuracyRow> = Vec::new();
    let mut extractors = accuracy::extractors();
    let mut sphere_truths: Vec<Truth> = Vec::new();
    for (name, map) in &maps {
        for &domain in &domains {
            bar.set_message(format!("accuracy: {name} ({})", domain.name()));
            let truth = Truth::new(map, domain);
            rows.extend(accuracy::evaluate_map(
                &mut extractors,
                name,
                map,
                domain,
                &truth,
                &plan.counts,
                plan.reps,
                || bar.inc(1),
            ));
            if domain == Domain::Sphere {
                sphere_truths.push(truth);
            }
        }
    }
    write(&opts.out.join("accuracy.csv"), &accuracy::to_csv(&rows))?;
    charts::error_vs_lights(
        &rows,
        Domain::Sphere,
        &plan.counts,
        None,
        &opts.out.join("error_vs_lights.svg"),
    )?;
    charts::error_vs_lights(
        &rows,
        Domain::Sphere,
        &plan.counts,
        Some(1),
        &opts.out.join("glossy_vs_lights.svg"),
    )?;
    charts::error_vs_time(
        &rows,
        Domain::Sphere,
        &plan.counts,
        &opts.out.join("error_vs_time.svg"),
    )?;
    let accuracy_md = accuracy_markdown(&rows, &domains);
    write(&opts.out.join("accuracy.md"), &accuracy_md)?;
    let per_map_md = per_map::markdown(&rows, Domain::Sphere);
    write(&opts.out.join("per_map.md"), &per_map_md)?;
    // The upper hemisphere, a sky camera's domain, where `--upper` measured it.
    let per_map_upper_md = if opts.upper {
        let md = per_map::markdown(&rows, Domain::Upper);
        write(&opts.out.join("per_map_upper.md"), &md)?;
        md
    } else {
        String::new()
    };

    // 1b. The placement frontier of the default method (diffuse against shadowed).
    bar.set_message("placement frontier");
    let frontier_counts: Vec<usize> = [16, 64, 256]
        .into_iter()
        .filter(|n| plan.counts.contains(n))
        .collect();
    let frontier_rows = per_map::frontier(&maps, &sphere_truths, &rows, &frontier_counts);
    write(
        &opts.out.join("frontier.csv"),
        &per_map::frontier_csv(&frontier_rows),
    )?;
    charts::frontier(&frontier_rows, &opts.out.join("frontier.svg"))?;
    let frontier_md = per_map::frontier_markdown(&frontier_rows);
    write(&opts.out.join("frontier.md"), &frontier_md)?;

    // 1c. A client's shadow budget: K shadowed lights, with and without the remainder SH.
    bar.set_message("shadow budget");
    let mut budget_rows = Vec::new();
    for ((name, map), truth) in maps.iter().zip(&sphere_truths) {
        budget_rows.extend(budget::evaluate_map(name, map, truth));
    }
    write(&opts.out.join("budget.csv"), &budget::to_csv(&budget_rows))?;
    // The adaptive count over time: the default sky of `vemlight serve`, and a map turning.
    let adaptive_frames = if opts.quick { 150 } else { 1800 };
    let mut adaptive_rows = Vec::new();
    for target in budget::ADAPTIVE_TARGETS {
        bar.set_message(format!("adaptive count, E = {target}"));
        let mut sky = crate::sky::SyntheticSky::new(crate::sky::SyntheticConfig::default());
        adaptive_rows.push(budget::adaptive_run(
            "default sky (serve)",
            adaptive_frames,
            30.0,
            target,
            |k| sky.render(k as f64 / 30.0),
        ));
        if let Some((name, map)) = maps.iter().find(|(n, _)| n == SEQUENCE_MAP) {
            let dirs = LatLongDirs::new(map.width, map.height);
            let step = ROTATION_DEG_PER_FRAME.to_radians();
            adaptive_rows.push(budget::adaptive_run(
                &format!("{name}:yaw"),
                adaptive_frames,
                30.0,
                target,
                |k| dirs.rotated(map, DQuat::from_rotation_y(step * k as f64)),
            ));
        }
    }
    let budget_md = format!(
        "{}
{}",
        budget::markdown(&budget_rows),
        budget::adaptive_markdown(&adaptive_rows)
    );
    write(&opts.out.join("budget.md"), &budget_md)?;

    // 1d. The targets at counts between the powers of two.
    let mut between_rows = Vec::new();
    for ((name, map), truth) in maps.iter().zip(&sphere_truths) {
        bar.set_message(format!("counts between: {name}"));
        between_rows.extend(between::evaluate_map(name, map, truth, &plan.between));
        bar.inc(1);
    }
    write(
        &opts.out.join("between.csv"),
        &between::to_csv(&between_rows),
    )?;
    let between_md = between::markdown(&between_rows);
    write(&opts.out.join("between.md"), &between_md)?;
    let accuracy_s = started.elapsed().as_secs_f64();

    // 2. Temporal stability.
    let t_temporal = Instant::now();
    let base = maps
        .iter()
        .find(|(n, _)| n == SEQUENCE_MAP)
        .unwrap_or(&maps[0]);
    let mut temporal_rows: Vec<TemporalRow> = Vec::new();
    let mut seqs = sequences_for(&base.0, &base.1, plan.frames);
    // Slow rotations of every map (ALGORITHMS.md §11), beside the base map's own sequences.
    for (name, map) in &maps {
        if name != &base.0 {
            seqs.extend(rotations_for(name, map, plan.frames));
        }
    }
    for mut seq in seqs {
        bar.set_message(format!("temporal: {}", seq.name));
        temporal_rows.extend(run_sequence(
            &mut seq,
            TEMPORAL_N,
            Domain::Sphere,
            true,
            || bar.inc(1),
        ));
    }
    write(
        &opts.out.join("temporal.csv"),
        &temporal::to_csv(&temporal_rows),
    )?;
    charts::temporal(&temporal_rows, &opts.out.join("temporal.svg"))?;
    let temporal_md = temporal_markdown(&temporal_rows);
    write(&opts.out.join("temporal.md"), &temporal_md)?;
    let temporal_s = t_temporal.elapsed().as_secs_f64();

    // 3. Hard cases.
    let t_hard = Instant::now();
    bar.set_message("stability: hard cases");
    let stab = stability::run(&hard, || bar.inc(1));
    write(&opts.out.join("stability.csv"), &stability::to_csv(&stab))?;
    let stability_md = stability::to_markdown(&hard, &stab);
    write(&opts.out.join("stability.md"), &stability_md)?;
    let hard_s = t_hard.elapsed().as_secs_f64();
    bar.finish_and_clear();

    let total_s = started.elapsed().as_secs_f64();
    let run_md = format!(
        "`vemlight eval{}` on {} maps ({} domain{}): accuracy {:.0} s, temporal {:.0} s, hard cases {:.0} s, **total {:.0} s** on {} CPU core(s).\n",
        if opts.quick { " --quick" } else { "" },
        maps.len(),
        domains
            .iter()
            .map(|d| d.name())
            .collect::<Vec<_>>()
            .join(" + "),
        if domains.len() > 1 { "s" } else { "" },
        accuracy_s,
        temporal_s,
        hard_s,
        total_s,
        std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1),
    );
    write(&opts.out.join("run.md"), &run_md)?;
    if let Some(doc) = &opts.doc
        && doc.exists()
    {
        let mut text = std::fs::read_to_string(doc)?;
        for (name, body) in [
            ("accuracy", &accuracy_md),
            ("per-map", &per_map_md),
            ("between", &between_md),
            ("frontier", &frontier_md),
            ("budget", &budget_md),
            ("temporal", &temporal_md),
            ("stability", &stability_md),
            ("run", &run_md),
        ] {
            text = replace_section(&text, name, body);
        }
        if opts.upper {
            text = replace_section(&text, "per-map-upper", &per_map_upper_md);
        }
        write(doc, &text)?;
    }
    Ok(format!(
        "{accuracy_md}\n{per_map_md}\n{per_map_upper_md}\n{between_md}\n{frontier_md}\n{budget_md}\n{temporal_md}\n{run_md}"
    ))
}

/// Decodes every .exr/.hdr file of a directory, sorted by name.
fn load_maps(dir: &Path) -> anyhow::Result<Vec<(String, EnvMap)>> {
    crate::capture::files::list_frames(dir)?
        .into_iter()
        .map(|p| {
            let name = p
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            Ok((name, EnvMap::open(&p, None, DEFAULT_MAX_PIXELS)?))
        })
        .collect()
}

/// Yaw and pitch at [`ROTATION_DEG_PER_FRAME`] of one map, named `map:yaw`, `map:pitch`.
fn rotations_for<'a>(name: &str, map: &'a EnvMap, frames: usize) -> Vec<Sequence<'a>> {
    let dirs = std::rc::Rc::new(LatLongDirs::new(map.width, map.height));
    let step = ROTATION_DEG_PER_FRAME.to_radians();
    let (d1, d2) = (dirs.clone(), dirs);
    vec![
        Sequence {
            name: format!("{name}:yaw"),
            description: format!("{name} rotated {ROTATION_DEG_PER_FRAME}°/frame about +Y"),
            frames,
            render: Box::new(move |t| d1.rotated(map, DQuat::from_rotation_y(step * t as f64))),
            turn_per_frame: Some(DQuat::from_rotation_y(step)),
        },
        Sequence {
            name: format!("{name}:pitch"),
            description: format!("{name} rotated {ROTATION_DEG_PER_FRAME}°/frame about +X"),
            frames,
            render: Box::new(move |t| d2.rotated(map, DQuat::from_rotation_x(step * t as f64))),
            turn_per_frame: Some(DQuat::from_rotation_x(step)),
        },
    ]
}

/// The temporal sequences (ALGORITHMS.md §11), rendered on demand.
fn sequences_for<'a>(name: &str, map: &'a EnvMap, frames: usize) -> Vec<Sequence<'a>> {
    let on_frame = frames / 2;
    let lamp = with_lamp(map, dir_from_elev_azim(25.0, -120.0), 2.0, 0.25);
    let mut sky = SyntheticSky::new(SyntheticConfig {
        start_elevation_deg: 20.0,
        // 0.25° per frame at 30 frames/s.
        sun_speed_deg_per_s: ROTATION_DEG_PER_FRAME * 30.0,
        switch_light: None,
        ..SyntheticConfig::default()
    });
    let mut seqs = rotations_for(name, map, frames);
    seqs.extend([
        Sequence {
            name: "sun-path".into(),
            description: "the synthetic sky (Hosek-Wilkie, clouds drifting 2°/s), sun moving 0.25°/frame at 30 frames/s".into(),
            frames,
            render: Box::new(move |t| sky.render(t as f64 / 30.0)),
            turn_per_frame: None,
        },
        Sequence {
            name: "exposure".into(),
            description: format!("{name}, exposure ramp of +1 % per frame"),
            frames,
            render: Box::new(move |t| scaled(map, 1.01f32.powi(t as i32))),
            turn_per_frame: None,
        },
        Sequence {
            name: "switch-on".into(),
            description: format!(
                "{name} with a lamp of 25 % of its energy switched on at frame {on_frame}"
            ),
            frames,
            render: Box::new(move |t| if t < on_frame { map.clone() } else { lamp.clone() }),
            turn_per_frame: None,
        },
    ]);
    seqs
}

/// The accuracy table: median over maps at N = 16, 64, 256, and the targets of docs/EVALUATION.md.
fn accuracy_markdown(rows: &[AccuracyRow], domains: &[Domain]) -> String {
    let mut s = String::new();
    let show: Vec<usize> = [16, 64, 256]
        .into_iter()
        .filter(|n| rows.iter().any(|r| r.lights == Some(*n)))
        .collect();
    for &domain in domains {
        s += &format!(
            "\n**{}** — median over maps (min–max), relative RMS; time = median ms per frame, single thread\n\n",
            domain.name()
        );
        s += "| method | N | diffuse | diffuse max | glossy 32 | glossy 128 | ms/frame |\n|---|---|---|---|---|---|---|\n";
        let mut methods: Vec<&str> = crate::lights::Method::ALL
            .iter()
            .map(|m| m.name())
            .collect();
        methods.push(SH_NAME);
        for m in methods {
            let counts: Vec<Option<usize>> = if m == SH_NAME {
                vec![None]
            } else {
                show.iter().map(|&n| Some(n)).collect()
            };
            for n in counts {
                let cell = |f: &dyn Fn(&AccuracyRow) -> Option<f64>| {
                    spread(rows, domain, m, n, f)
                        .map(|s| {
                            format!(
                                "{} ({}–{})",
                                fmt_pct(s.median),
                                fmt_pct(s.min),
                                fmt_pct(s.max)
                            )
                        })
                        .unwrap_or_else(|| "—".into())
                };
                let ms = spread(rows, domain, m, n, |r: &AccuracyRow| Some(r.time_s * 1e3))
                    .map(|s| format!("{:.2}", s.median))
                    .unwrap_or_default();
                s += &format!(
                    "| {m} | {} | {} | {} | {} | {} | {ms} |\n",
                    n.map(|n| n.to_string())
                        .unwrap_or_else(|| "9 coeff.".into()),
                    cell(&|r| Some(r.diffuse.rel_rms)),
                    cell(&|r| Some(r.diffuse.rel_max)),
                    cell(&|r| r.glossy[0]),
                    cell(&|r| r.glossy[1]),
                );
            }
        }
        // The targets (default vs median cut, median over maps).
        s += "\nTargets (default `voronoi` against `median-cut`, median over maps):\n\n| N | diffuse voronoi | diffuse median cut | ≤ ? | glossy 32 voronoi / mc | glossy 128 voronoi / mc | ≤ ? (N ≥ 64) |\n|---|---|---|---|---|---|---|\n";
        let med = |m: &str, n: usize, f: &dyn Fn(&AccuracyRow) -> Option<f64>| {
            spread(rows, domain, m, Some(n), f)
                .map(|s| s.median)
                .unwrap_or(f64::NAN)
        };
        for n in rows
            .iter()
            .filter(|r| r.domain == domain)
            .filter_map(|r| r.lights)
            .collect::<std::collections::BTreeSet<_>>()
        {
            let (dv, dm) = (
                med("voronoi", n, &|r| Some(r.diffuse.rel_rms)),
                med("median-cut", n, &|r| Some(r.diffuse.rel_rms)),
            );
            let g: Vec<(f64, f64)> = (0..2)
                .map(|k| {
                    (
                        med("voronoi", n, &|r| r.glossy[k]),
                        med("median-cut", n, &|r| r.glossy[k]),
                    )
                })
                .collect();
            let diffuse_ok = if n >= 16 {
                if dv <= dm { "yes" } else { "**no**" }
            } else {
                "(N < 16)"
            };
            let glossy_ok = if n >= 64 {
                if g.iter().all(|(v, m)| v <= m) {
                    "yes"
                } else {
                    "**no**"
                }
            } else {
                "(N < 64)"
            };
            s += &format!(
                "| {n} | {} | {} | {diffuse_ok} | {} / {} | {} / {} | {glossy_ok} |\n",
                fmt_pct(dv),
                fmt_pct(dm),
                fmt_pct(g[0].0),
                fmt_pct(g[0].1),
                fmt_pct(g[1].0),
                fmt_pct(g[1].1),
            );
        }
    }
    s
}

/// The temporal table: one row per sequence and method, raw and filtered side by side.
fn temporal_markdown(rows: &[TemporalRow]) -> String {
    let mut s = format!(
        "N = {TEMPORAL_N}, whole sphere, {} normals. Flicker ratio: 1 is perfect. Speed: mean / 99th percentile / max of a light id's angle between consecutive frames. Delay: nominal group delay / lag that best aligns E_N with E (frames). `{}`: on a turned map, the default's first-frame lights turned exactly with it at each frame's energy, what perfect tracking of that set would give (its floor; ALGORITHMS.md §11).\n\n| sequence | method | flicker raw | flicker FIR | error raw | speed raw (°/frame) | speed FIR (°/frame) | delay FIR |\n|---|---|---|---|---|---|---|---|\n",
        temporal::TEMPORAL_NORMALS,
        temporal::RIGID_NAME
    );
    let mut seen: Vec<(&str, &str)> = Vec::new();
    for r in rows {
        if seen.contains(&(&r.sequence, &r.method)) {
            continue;
        }
        seen.push((&r.sequence, &r.method));
        let fir = rows
            .iter()
            .find(|f| f.sequence == r.sequence && f.method == r.method && f.filter == "fir");
        let speed = |r: &TemporalRow| {
            if r.lights == 0 {
                "—".to_string()
            } else {
                format!(
                    "{:.3} / {:.2} / {:.1}",
                    r.speed_mean_deg, r.speed_p99_deg, r.speed_max_deg
                )
            }
        };
        s += &format!(
            "| {} | {} | {:.2} | {} | {} | {} | {} | {} |\n",
            r.sequence,
            r.method,
            r.flicker,
            fir.map(|f| format!("{:.2}", f.flicker))
                .unwrap_or_else(|| "—".into()),
            fmt_pct(r.rel_rms),
            speed(r),
            fir.map(speed).unwrap_or_else(|| "—".into()),
            fir.map(|f| format!("{} / {}", f.delay_nominal, f.delay_measured))
                .unwrap_or_else(|| format!("0 / {}", r.delay_measured)),
        );
    }
    s + &rigid_summary(rows)
}

/// The default's worst flicker through the FIR beside its rigid floor, and its worst excess
/// over that floor, over the turned maps.
fn rigid_summary(rows: &[TemporalRow]) -> String {
    let fir = |method: &str, sequence: &str| {
        rows.iter()
            .find(|r| r.method == method && r.sequence == sequence && r.filter == "fir")
            .map(|r| r.flicker)
    };
    let pairs: Vec<(&str, f64, f64)> = rows
        .iter()
        .filter(|r| r.method == temporal::RIGID_NAME && r.filter == "fir")
        .filter_map(|r| {
            let default = fir(crate::lights::Method::Voronoi.name(), &r.sequence)?;
            Some((r.sequence.as_str(), default, r.flicker))
        })
        .collect();
    let worst = pairs.iter().max_by(|a, b| a.1.total_cmp(&b.1));
    let excess = pairs
        .iter()
        .max_by(|a, b| (a.1 - a.2).total_cmp(&(b.1 - b.2)));
    match (worst, excess) {
        (Some(w), Some(e)) => format!(
            "\nDefault through the FIR on the turned maps: worst {:.3} ({}; its rigid floor {:.3}); largest excess over the floor {:+.3} ({}: {:.3} against {:.3}).\n",
            w.1,
            w.0,
            w.2,
            e.1 - e.2,
            e.0,
            e.1,
            e.2
        ),
        _ => String::new(),
    }
}

/// Replaces the text between `<!-- BEGIN name -->` and `<!-- END name -->` (kept) with `body`.
fn replace_section(text: &str, name: &str, body: &str) -> String {
    let (begin, end) = (
        format!("<!-- BEGIN {name} -->"),
        format!("<!-- END {name} -->"),
    );
    match (text.find(&begin), text.find(&end)) {
        (Some(b), Some(e)) if b < e => {
            format!("{}{begin}\n{}\n{}", &text[..b], body.trim_end(), &text[e..])
        }
        _ => text.to_string(),
    }
}

fn write(path: &Path, text: &str) -> anyhow::Result<()> {
    std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))
}
