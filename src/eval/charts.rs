//! SVG charts of the evaluation (plotters): error against light count, error against time per
//! frame, and flicker per sequence.
//!
//! Input: the rows of accuracy.csv and temporal.csv. Output: small self-contained SVG files.

use super::accuracy::{AccuracyRow, SH_NAME, spread};
use super::temporal::TemporalRow;
use crate::lights::Method;
use crate::mapping::Domain;
use anyhow::anyhow;
use plotters::prelude::*;
use std::path::Path;

const SIZE: (u32, u32) = (820, 520);
/// Top of the flicker chart's axis; taller bars are clipped and labelled.
const FLICKER_CAP: f64 = 3.0;

/// One colour per method (the SH line last), stable across charts.
fn colour(method: &str) -> RGBColor {
    match method {
        "voronoi" => RGBColor(31, 119, 180),
        "paper" => RGBColor(44, 160, 44),
        "median-cut" => RGBColor(214, 39, 40),
        "inverse-cdf" => RGBColor(148, 103, 189),
        "vmlps" => RGBColor(255, 127, 14),
        "k-means" => RGBColor(23, 190, 207),
        _ => RGBColor(90, 90, 90),
    }
}

/// A log-log chart on an SVG file.
type LogLogChart<'a, 'b> =
    ChartContext<'a, SVGBackend<'b>, Cartesian2d<LogCoord<f64>, LogCoord<f64>>>;

/// One method's median line with a dot at each point and its legend entry.
fn draw_method_line(
    chart: &mut LogLogChart<'_, '_>,
    line: &[(f64, f64)],
    c: RGBColor,
    name: &str,
) -> anyhow::Result<()> {
    chart
        .draw_series(LineSeries::new(line.to_vec(), c.stroke_width(2)))
        .map_err(plot_err)?
        .label(name)
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2)));
    chart
        .draw_series(line.iter().map(|&p| Circle::new(p, 3, c.filled())))
        .map_err(plot_err)?;
    Ok(())
}

fn plot_err<E: std::fmt::Debug>(e: E) -> anyhow::Error {
    anyhow!("drawing the chart: {e:?}")
}

/// error_vs_lights.svg: median diffuse error over maps against N, one line per method, the band
/// from the best to the worst map, and the SH error as a dashed horizontal line. With
/// `glossy = Some(k)`, the glossy error of exponent index k instead (no SH line).
pub fn error_vs_lights(
    rows: &[AccuracyRow],
    domain: Domain,
    counts: &[usize],
    glossy: Option<usize>,
    path: &Path,
) -> anyhow::Result<()> {
    let value = |r: &AccuracyRow| match glossy {
        None => Some(r.diffuse.rel_rms),
        Some(k) => r.glossy[k],
    };
    let (lo, hi) = value_range(rows, domain, &value);
    let root = SVGBackend::new(path, SIZE).into_drawing_area();
    root.fill(&WHITE).map_err(plot_err)?;
    let title = match glossy {
        None => format!("Diffuse irradiance error vs lights ({})", domain.name()),
        Some(k) => format!(
            "Glossy (Phong {}) error vs lights ({})",
            crate::lights::error::GLOSSY_EXPONENTS[k],
            domain.name()
        ),
    };
    let (n0, n1) = (
        *counts.first().unwrap_or(&8) as f64,
        *counts.last().unwrap_or(&1024) as f64,
    );
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(42)
        .y_label_area_size(64)
        .build_cartesian_2d((n0..n1).log_scale(), (lo..hi).log_scale())
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .x_desc("lights N")
        .y_desc("relative RMS error (median over maps; band: min–max)")
        .x_label_formatter(&|x| format!("{x:.0}"))
        .y_label_formatter(&|y| format_pct(*y))
        .draw()
        .map_err(plot_err)?;
    for method in Method::ALL {
        let name = method.name();
        let c = colour(name);
        let pts: Vec<(f64, Option<super::accuracy::Spread>)> = counts
            .iter()
            .map(|&n| (n as f64, spread(rows, domain, name, Some(n), value)))
            .collect();
        let band: Vec<(f64, f64)> = pts
            .iter()
            .filter_map(|(n, s)| s.map(|s| (*n, s.max.max(lo))))
            .chain(
                pts.iter()
                    .rev()
                    .filter_map(|(n, s)| s.map(|s| (*n, s.min.max(lo)))),
            )
            .collect();
        if band.len() >= 4 {
            chart
                .draw_series(std::iter::once(Polygon::new(band, c.mix(0.12))))
                .map_err(plot_err)?;
        }
        let line: Vec<(f64, f64)> = pts
            .iter()
            .filter_map(|(n, s)| s.map(|s| (*n, s.median.max(lo))))
            .collect();
        draw_method_line(&mut chart, &line, c, name)?;
    }
    if glossy.is_none()
        && let Some(s) = spread(rows, domain, SH_NAME, None, value)
    {
        let c = colour(SH_NAME);
        let y = s.median.max(lo);
        chart
            .draw_series(DashedLineSeries::new(
                vec![(n0, y), (n1, y)],
                6,
                4,
                c.stroke_width(2),
            ))
            .map_err(plot_err)?
            .label("L2 SH (diffuse only, no lights)")
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2)));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(plot_err)?;
    root.present().map_err(plot_err)?;
    Ok(())
}

/// error_vs_time.svg: median diffuse error over maps against median time per frame (single
/// thread), one line per method through N = 8 … 1024, and the SH point.
pub fn error_vs_time(
    rows: &[AccuracyRow],
    domain: Domain,
    counts: &[usize],
    path: &Path,
) -> anyhow::Result<()> {
    let err = |r: &AccuracyRow| Some(r.diffuse.rel_rms);
    let time = |r: &AccuracyRow| Some(r.time_s * 1e3);
    let (lo, hi) = value_range(rows, domain, &err);
    let times: Vec<f64> = rows
        .iter()
        .filter(|r| r.domain == domain)
        .map(|r| r.time_s * 1e3)
        .filter(|t| *t > 0.0)
        .collect();
    let t_lo = times.iter().copied().fold(f64::INFINITY, f64::min) * 0.7;
    let t_hi = times.iter().copied().fold(0.0, f64::max) * 1.4;
    let root = SVGBackend::new(path, SIZE).into_drawing_area();
    root.fill(&WHITE).map_err(plot_err)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            format!("Diffuse error vs time per frame ({})", domain.name()),
            ("sans-serif", 20),
        )
        .margin(12)
        .x_label_area_size(42)
        .y_label_area_size(64)
        .build_cartesian_2d((t_lo..t_hi).log_scale(), (lo..hi).log_scale())
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .x_desc("median time per frame, ms (single thread, resampling included, decode excluded)")
        .y_desc("relative RMS error (median over maps)")
        .x_label_formatter(&|x| {
            if *x >= 1.0 {
                format!("{x:.0}")
            } else {
                format!("{x:.2}")
            }
        })
        .y_label_formatter(&|y| format_pct(*y))
        .draw()
        .map_err(plot_err)?;
    for method in Method::ALL {
        let name = method.name();
        let c = colour(name);
        let line: Vec<(f64, f64)> = counts
            .iter()
            .filter_map(|&n| {
                let e = spread(rows, domain, name, Some(n), err)?;
                let t = spread(rows, domain, name, Some(n), time)?;
                Some((t.median, e.median.max(lo)))
            })
            .collect();
        draw_method_line(&mut chart, &line, c, name)?;
        // Label the ends with their light counts.
        for (k, &p) in line.iter().enumerate() {
            if k == 0 || k + 1 == line.len() {
                chart
                    .draw_series(std::iter::once(Text::new(
                        format!("N={}", counts[k]),
                        p,
                        ("sans-serif", 11).into_font().color(&c),
                    )))
                    .map_err(plot_err)?;
            }
        }
    }
    if let (Some(e), Some(t)) = (
        spread(rows, domain, SH_NAME, None, err),
        spread(rows, domain, SH_NAME, None, time),
    ) {
        let c = colour(SH_NAME);
        chart
            .draw_series(std::iter::once(TriangleMarker::new(
                (t.median, e.median.max(lo)),
                6,
                c.filled(),
            )))
            .map_err(plot_err)?
            .label("L2 SH (diffuse only, no lights)")
            .legend(move |(x, y)| TriangleMarker::new((x + 10, y), 5, c.filled()));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(plot_err)?;
    root.present().map_err(plot_err)?;
    Ok(())
}

/// temporal.svg: flicker ratio per sequence, grouped bars per method, without and with the FIR
/// (the lighter bar is filtered); a line at 1 (perfect).
pub fn temporal(rows: &[TemporalRow], path: &Path) -> anyhow::Result<()> {
    let mut sequences: Vec<String> = Vec::new();
    for r in rows {
        if !sequences.contains(&r.sequence) {
            sequences.push(r.sequence.clone());
        }
    }
    let methods: Vec<&str> = Method::ALL.iter().map(|m| m.name()).collect();
    // Bars above the cap are clipped and labelled with their value (median cut through the FIR
    // reaches ~8, which would flatten every other bar).
    let hi = rows
        .iter()
        .map(|r| r.flicker)
        .filter(|f| f.is_finite())
        .fold(1.0f64, f64::max)
        .min(FLICKER_CAP)
        * 1.12;
    let slots = methods.len() * 2 + 1;
    let width = (sequences.len() * slots) as f64;
    let root = SVGBackend::new(path, (SIZE.0 + 120, SIZE.1)).into_drawing_area();
    root.fill(&WHITE).map_err(plot_err)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "Flicker ratio (TV of E_N over TV of E; 1 = perfect): solid = raw, light = 9-tap FIR",
            ("sans-serif", 18),
        )
        .margin(12)
        .x_label_area_size(20)
        .y_label_area_size(56)
        .build_cartesian_2d(0f64..width, 0f64..hi)
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_label_formatter(&|_| String::new())
        .y_desc("flicker ratio")
        .draw()
        .map_err(plot_err)?;
    // Sequence names above each group.
    chart
        .draw_series(sequences.iter().enumerate().map(|(si, s)| {
            Text::new(
                s.clone(),
                (si as f64 * slots as f64 + 0.6, hi * 0.985),
                ("sans-serif", 14).into_font(),
            )
        }))
        .map_err(plot_err)?;
    for (mi, m) in methods.iter().enumerate() {
        let c = colour(m);
        for (fi, filter) in ["none", "fir"].iter().enumerate() {
            let style = if fi == 0 {
                c.filled()
            } else {
                c.mix(0.4).filled()
            };
            let bars: Vec<Rectangle<(f64, f64)>> = sequences
                .iter()
                .enumerate()
                .filter_map(|(si, s)| {
                    let r = rows
                        .iter()
                        .find(|r| &r.sequence == s && r.method == *m && r.filter == *filter)?;
                    let x0 = (si * slots + mi * 2 + fi) as f64 + 0.5;
                    Some(Rectangle::new(
                        [(x0, 0.0), (x0 + 0.9, r.flicker.min(FLICKER_CAP))],
                        style,
                    ))
                })
                .collect();
            let series = chart.draw_series(bars).map_err(plot_err)?;
            if fi == 0 {
                series.label(*m).legend(move |(x, y)| {
                    Rectangle::new([(x, y - 5), (x + 14, y + 5)], c.filled())
                });
            }
            let clipped: Vec<(f64, f64)> = sequences
                .iter()
                .enumerate()
                .filter_map(|(si, s)| {
                    let r = rows
                        .iter()
                        .find(|r| &r.sequence == s && r.method == *m && r.filter == *filter)?;
                    (r.flicker > FLICKER_CAP)
                        .then(|| ((si * slots + mi * 2 + fi) as f64 + 0.3, r.flicker))
                })
                .collect();
            chart
                .draw_series(clipped.into_iter().map(|(x, f)| {
                    Text::new(
                        format!("{f:.1}"),
                        (x, FLICKER_CAP * 1.03),
                        ("sans-serif", 10).into_font(),
                    )
                }))
                .map_err(plot_err)?;
        }
    }
    chart
        .draw_series(DashedLineSeries::new(
            vec![(0.0, 1.0), (width, 1.0)],
            6,
            4,
            BLACK.stroke_width(1),
        ))
        .map_err(plot_err)?;
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(plot_err)?;
    root.present().map_err(plot_err)?;
    Ok(())
}

/// A log-axis range that holds every finite positive value of the domain's rows.
fn value_range(
    rows: &[AccuracyRow],
    domain: Domain,
    value: &impl Fn(&AccuracyRow) -> Option<f64>,
) -> (f64, f64) {
    let v: Vec<f64> = rows
        .iter()
        .filter(|r| r.domain == domain)
        .filter_map(value)
        .filter(|x| x.is_finite() && *x > 0.0)
        .collect();
    let lo = v.iter().copied().fold(f64::INFINITY, f64::min).max(1e-6);
    let hi = v.iter().copied().fold(0.0, f64::max);
    if !(lo.is_finite() && hi > lo) {
        return (1e-4, 1.0);
    }
    (lo * 0.7, hi * 1.5)
}

fn format_pct(y: f64) -> String {
    let p = y * 100.0;
    if p >= 1.0 {
        format!("{p:.0}%")
    } else if p >= 0.1 {
        format!("{p:.1}%")
    } else {
        format!("{p:.2}%")
    }
}

/// frontier.svg: each placement of the default method as a point (worst map over the sweep's
/// maps and counts): diffuse ÷ k-means against shadowed ÷ median cut, both log scale, with the
/// targets (1.25 and 1) as lines; one colour per density exponent, labelled by its cap.
pub fn frontier(rows: &[super::per_map::FrontierRow], path: &Path) -> anyhow::Result<()> {
    use super::per_map::{by_placement, worst_of};
    let points: Vec<(f64, f64, f32, f32)> = by_placement(rows)
        .into_iter()
        .map(|(p, rs)| {
            let ((d, _), (s, _)) = worst_of(&rs);
            (d, s, p.exponent, p.max_seeds_per_texel)
        })
        .filter(|p| p.0.is_finite() && p.1.is_finite() && p.0 > 0.0 && p.1 > 0.0)
        .collect();
    let root = SVGBackend::new(path, SIZE).into_drawing_area();
    root.fill(&WHITE).map_err(plot_err)?;
    let fold = |f: fn(f64, f64) -> f64, init: f64, g: fn(&(f64, f64, f32, f32)) -> f64| {
        points.iter().map(g).fold(init, f)
    };
    let x0 = fold(f64::min, 1.0, |p| p.0) * 0.8;
    let x1 = fold(f64::max, 1.25, |p| p.0) * 1.25;
    let y0 = fold(f64::min, 1.0, |p| p.1) * 0.8;
    let y1 = fold(f64::max, 1.0, |p| p.1) * 1.25;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "Placement frontier of the default method (worst map and N)",
            ("sans-serif", 20),
        )
        .margin(12)
        .x_label_area_size(42)
        .y_label_area_size(64)
        .build_cartesian_2d((x0..x1).log_scale(), (y0..y1).log_scale())
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .x_desc("diffuse error ÷ converged k-means (target ≤ 1.25)")
        .y_desc("shadowed error ÷ median cut (target ≤ 1)")
        .x_label_formatter(&|x| format!("{x:.2}"))
        .y_label_formatter(&|y| format!("{y:.2}"))
        .draw()
        .map_err(plot_err)?;
    let grey = RGBColor(150, 150, 150);
    chart
        .draw_series(LineSeries::new(
            vec![(1.25, y0), (1.25, y1)],
            grey.stroke_width(1),
        ))
        .map_err(plot_err)?;
    chart
        .draw_series(LineSeries::new(
            vec![(x0, 1.0), (x1, 1.0)],
            grey.stroke_width(1),
        ))
        .map_err(plot_err)?;
    let palette = [
        RGBColor(31, 119, 180),
        RGBColor(44, 160, 44),
        RGBColor(255, 127, 14),
        RGBColor(148, 103, 189),
        RGBColor(214, 39, 40),
    ];
    let mut exponents: Vec<f32> = points.iter().map(|p| p.2).collect();
    exponents.sort_by(f32::total_cmp);
    exponents.dedup();
    for (k, e) in exponents.iter().enumerate() {
        let c = palette[k % palette.len()];
        let pts: Vec<&(f64, f64, f32, f32)> = points.iter().filter(|p| p.2 == *e).collect();
        chart
            .draw_series(pts.iter().map(|p| Circle::new((p.0, p.1), 5, c.filled())))
            .map_err(plot_err)?
            .label(format!("exponent {e}"))
            .legend(move |(x, y)| Circle::new((x + 10, y), 5, c.filled()));
        chart
            .draw_series(pts.iter().map(|p| {
                let cap = if p.3 > 0.0 {
                    format!("cap {}", p.3)
                } else {
                    "no cap".into()
                };
                Text::new(cap, (p.0 * 1.03, p.1), ("sans-serif", 11).into_font())
            }))
            .map_err(plot_err)?;
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(plot_err)?;
    root.present().map_err(plot_err)?;
    Ok(())
}
