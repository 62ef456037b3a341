//! The benchmark's SVG plots (plotters, SVG backend: no fonts or system libraries needed):
//! rotation error against rotation step per method, per-object error bars, time per stage.

use crate::pairs::PairResult;
use anyhow::Context;
use flowfilter_pipeline::StageTimes;
use plotters::coord::Shift;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// One (object, method) cell of the summary, as the plots need it.
pub struct MethodObject {
    /// Object name (`ALL` for every object).
    pub object: String,
    /// Method.
    pub method: String,
    /// Mean rotation-angle error, degrees.
    pub mean_angle_error_deg: Option<f64>,
    /// Mean per-stage times.
    pub stage_ms: Option<StageTimes>,
}

const COLOURS: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
];

fn colour(i: usize) -> RGBColor {
    COLOURS[i % COLOURS.len()]
}

/// Bars' legend swatch.
fn swatch(c: RGBColor) -> impl Fn((i32, i32)) -> Rectangle<(i32, i32)> {
    move |(x, y)| Rectangle::new([(x, y - 5), (x + 15, y + 5)], c.filled())
}

/// Labels for categories centred at 0.5, 1.5, ... on a continuous axis.
fn category_labels(labels: Vec<String>) -> impl Fn(&f64) -> String {
    move |v| {
        let i = (v - 0.5).round();
        if (v - 0.5 - i).abs() < 1e-6 && i >= 0.0 && (i as usize) < labels.len() {
            labels[i as usize].clone()
        } else {
            String::new()
        }
    }
}

/// Draw the legend box and write the file.
fn finish<'b>(
    chart: &mut ChartContext<'b, SVGBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
    root: &DrawingArea<SVGBackend<'b>, Shift>,
    position: SeriesLabelPosition,
) -> anyhow::Result<()> {
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .position(position)
        .draw()
        .map_err(plot_error)?;
    root.present().map_err(plot_error)?;
    Ok(())
}

fn plot_error(e: impl std::fmt::Display) -> anyhow::Error {
    anyhow::anyhow!("plotting: {e}")
}

/// Write the three plots into `dir`; returns their file names.
pub fn write_all(
    dir: &Path,
    pairs: &[PairResult],
    summary: &[MethodObject],
    methods: &[String],
) -> anyhow::Result<Vec<String>> {
    let names = ["error_vs_step.svg", "per_object.svg", "stage_times.svg"];
    error_vs_step(&dir.join(names[0]), pairs, methods).context(names[0])?;
    per_object(&dir.join(names[1]), summary, methods).context(names[1])?;
    stage_times(&dir.join(names[2]), summary, methods).context(names[2])?;
    Ok(names.iter().map(|s| s.to_string()).collect())
}

/// Mean rotation-angle error against the true rotation (the mean over each step's pairs), one
/// line per method.
fn error_vs_step(path: &Path, pairs: &[PairResult], methods: &[String]) -> anyhow::Result<()> {
    let mut acc: BTreeMap<(&str, u32), (f64, usize)> = BTreeMap::new();
    let mut motion: BTreeMap<u32, (f64, usize)> = BTreeMap::new();
    for p in pairs {
        if let Some(e) = &p.errors {
            let a = acc.entry((p.method.as_str(), p.step)).or_default();
            a.0 += e.angle_error_deg;
            a.1 += 1;
        }
        let m = motion.entry(p.step).or_default();
        m.0 += p.motion_deg.unwrap_or(f64::from(p.step));
        m.1 += 1;
    }
    let steps: BTreeSet<u32> = pairs.iter().map(|p| p.step).collect();
    let x_of = |s: u32| motion.get(&s).map_or(f64::from(s), |(sum, n)| sum / *n as f64);
    let (x0, x1) = (steps.first().map_or(0.0, |&s| x_of(s)), steps.last().map_or(30.0, |&s| x_of(s)));
    let ymax = acc.values().map(|(s, n)| s / *n as f64).fold(1.0f64, f64::max) * 1.1;
    let root = SVGBackend::new(path, (800, 500)).into_drawing_area();
    root.fill(&WHITE).map_err(plot_error)?;
    let mut chart = ChartBuilder::on(&root)
        .caption("Mean rotation-angle error vs true rotation", ("sans-serif", 22))
        .margin(15)
        .x_label_area_size(40)
        .y_label_area_size(55)
        .build_cartesian_2d((x0 - 0.05 * (x1 - x0) - 0.1)..(x1 + 0.05 * (x1 - x0) + 0.1), 0.0..ymax)
        .map_err(plot_error)?;
    chart
        .configure_mesh()
        .x_desc("true rotation (degrees)")
        .y_desc("mean rotation-angle error (degrees)")
        .draw()
        .map_err(plot_error)?;
    for (i, m) in methods.iter().enumerate() {
        let pts: Vec<(f64, f64)> = steps
            .iter()
            .filter_map(|&s| acc.get(&(m.as_str(), s)).map(|(sum, n)| (x_of(s), sum / *n as f64)))
            .collect();
        let c = colour(i);
        chart
            .draw_series(LineSeries::new(pts.clone(), c.stroke_width(2)))
            .map_err(plot_error)?
            .label(m.clone())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2)));
        chart.draw_series(pts.iter().map(|&p| Circle::new(p, 4, c.filled()))).map_err(plot_error)?;
    }
    finish(&mut chart, &root, SeriesLabelPosition::UpperLeft)
}

/// Grouped bars: mean rotation-angle error per object and method.
fn per_object(path: &Path, summary: &[MethodObject], methods: &[String]) -> anyhow::Result<()> {
    let objects: Vec<&str> = summary
        .iter()
        .map(|s| s.object.as_str())
        .collect::<BTreeSet<_>>()
        .into_iter()
        .filter(|o| *o != "ALL")
        .chain(std::iter::once("ALL"))
        .collect();
    let value =
        |o: &str, m: &str| summary.iter().find(|s| s.object == o && s.method == m).and_then(|s| s.mean_angle_error_deg);
    let ymax = summary.iter().filter_map(|s| s.mean_angle_error_deg).fold(1.0f64, f64::max) * 1.1;
    let width = (160 + objects.len() * 28 * methods.len().max(1)).clamp(800, 2400) as u32;
    let root = SVGBackend::new(path, (width, 520)).into_drawing_area();
    root.fill(&WHITE).map_err(plot_error)?;
    let n = objects.len() as f64;
    let mut chart = ChartBuilder::on(&root)
        .caption("Mean rotation-angle error per object", ("sans-serif", 22))
        .margin(15)
        .x_label_area_size(90)
        .y_label_area_size(55)
        .build_cartesian_2d(0.0..n, 0.0..ymax)
        .map_err(plot_error)?;
    let labels = category_labels(objects.iter().map(|o| o.to_string()).collect());
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(objects.len() * 2 + 1)
        .x_label_formatter(&labels)
        .y_desc("mean rotation-angle error (degrees)")
        .draw()
        .map_err(plot_error)?;
    let bw = 0.8 / methods.len().max(1) as f64;
    for (k, m) in methods.iter().enumerate() {
        let c = colour(k);
        let bars: Vec<Rectangle<(f64, f64)>> = objects
            .iter()
            .enumerate()
            .filter_map(|(i, o)| {
                value(o, m).map(|v| {
                    let x = i as f64 + 0.1 + k as f64 * bw;
                    Rectangle::new([(x, 0.0), (x + bw * 0.9, v)], c.filled())
                })
            })
            .collect();
        chart.draw_series(bars).map_err(plot_error)?.label(m.clone()).legend(swatch(c));
    }
    finish(&mut chart, &root, SeriesLabelPosition::UpperRight)
}

/// Stacked bars: mean time per stage for each method (all objects).
fn stage_times(path: &Path, summary: &[MethodObject], methods: &[String]) -> anyhow::Result<()> {
    let stages = |t: &StageTimes| -> [(&'static str, f64); 5] {
        [
            ("depth (model)", t.depth_model),
            ("depth (target)", t.depth_target),
            ("flow", t.flow),
            ("correspondences", t.correspondences),
            ("registration", t.registration),
        ]
    };
    let rows: Vec<(&str, StageTimes)> = methods
        .iter()
        .filter_map(|m| {
            summary
                .iter()
                .find(|s| s.object == "ALL" && &s.method == m)
                .and_then(|s| s.stage_ms)
                .map(|t| (m.as_str(), t))
        })
        .collect();
    let xmax = rows.iter().map(|(_, t)| stages(t).iter().map(|s| s.1).sum::<f64>()).fold(1.0f64, f64::max) * 1.45;
    let root = SVGBackend::new(path, (800, 160 + 50 * rows.len() as u32)).into_drawing_area();
    root.fill(&WHITE).map_err(plot_error)?;
    let n = rows.len() as f64;
    let mut chart = ChartBuilder::on(&root)
        .caption("Mean time per stage and pair (ms)", ("sans-serif", 22))
        .margin(15)
        .x_label_area_size(40)
        .y_label_area_size(130)
        .build_cartesian_2d(0.0..xmax, 0.0..n)
        .map_err(plot_error)?;
    let labels = category_labels(rows.iter().map(|r| r.0.to_string()).collect());
    chart
        .configure_mesh()
        .disable_y_mesh()
        .y_labels(rows.len() * 2 + 1)
        .y_label_formatter(&labels)
        .x_desc("milliseconds")
        .draw()
        .map_err(plot_error)?;
    for (k, name) in ["depth (model)", "depth (target)", "flow", "correspondences", "registration"].iter().enumerate() {
        let c = colour(k);
        let bars: Vec<Rectangle<(f64, f64)>> = rows
            .iter()
            .enumerate()
            .map(|(i, (_, t))| {
                let s = stages(t);
                let start: f64 = s[..k].iter().map(|v| v.1).sum();
                Rectangle::new([(start, i as f64 + 0.15), (start + s[k].1, i as f64 + 0.85)], c.filled())
            })
            .collect();
        chart.draw_series(bars).map_err(plot_error)?.label(name.to_string()).legend(swatch(c));
    }
    finish(&mut chart, &root, SeriesLabelPosition::LowerRight)
}
