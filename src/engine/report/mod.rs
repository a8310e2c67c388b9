//! Self-contained HTML report with inline SVG figures (plotters), built from
//! run artifacts on disk, so `mdpipe report DIR…` works on any finished run.
//!
//! Colours follow the paper: no MD red, Kernel I blue, Kernel II green;
//! truth dashed grey.

use crate::base::artifacts::{self, Measurement};
use crate::engine::calibrate::summary::{ParamSummary, Summary};
use crate::engine::diagnose::Diagnosis;
use anyhow::{Context, Result};
use plotters::prelude::*;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

pub const W: u32 = 560;
pub const H: u32 = 380;

pub fn kernel_colour(kernel: &str) -> RGBColor {
    match kernel {
        "none" => RGBColor(205, 40, 40),
        "I" => RGBColor(40, 90, 205),
        _ => RGBColor(30, 150, 60),
    }
}

pub const TRUTH: RGBColor = RGBColor(120, 120, 120);

/// One calibration's artifacts, read back from its folder.
pub struct RunArtifacts {
    pub dir: PathBuf,
    pub summary: Summary,
    pub names: Vec<String>,
    /// Draws per parameter, in `names` order.
    pub draws: Vec<Vec<f64>>,
    pub predictions: polars::prelude::DataFrame,
    pub data: Vec<Measurement>,
}

impl RunArtifacts {
    pub fn load(dir: &Path) -> Result<Self> {
        let summary: Summary = serde_json::from_str(
            &std::fs::read_to_string(dir.join("summary.json"))
                .with_context(|| format!("reading {}/summary.json", dir.display()))?,
        )
        .with_context(|| format!("parsing {}/summary.json", dir.display()))?;
        let post = artifacts::read_parquet(&dir.join("posterior.parquet"))?;
        let names = summary.parameter_order.clone();
        let mut draws = Vec::new();
        for n in &names {
            let c =
                post.column(n).with_context(|| format!("{}/posterior.parquet: missing column '{n}'", dir.display()))?;
            draws.push(c.f64()?.into_no_null_iter().collect());
        }
        let predictions = artifacts::read_parquet(&dir.join("predictions.parquet"))?;
        let data = artifacts::read_measurements(&dir.join("measurements.parquet"))?;
        Ok(RunArtifacts { dir: dir.to_path_buf(), summary, names, draws, predictions, data })
    }

    pub fn param(&self, name: &str) -> Option<&[f64]> {
        self.names.iter().position(|n| n == name).map(|i| self.draws[i].as_slice())
    }

    pub fn pred_col(&self, observable: &str, kind: &str, col: &str) -> Vec<f64> {
        let obs = self.predictions.column("observable").unwrap().str().unwrap();
        let kinds = self.predictions.column("kind").unwrap().str().unwrap();
        let rows =
            (0..self.predictions.height()).filter(|&i| obs.get(i) == Some(observable) && kinds.get(i) == Some(kind));
        // Older runs have no `truth` column: treat a missing column as unknown.
        match self.predictions.column(col).ok().and_then(|c| c.f64().ok()) {
            Some(vals) => rows.map(|i| vals.get(i).unwrap_or(f64::NAN)).collect(),
            None => rows.map(|_| f64::NAN).collect(),
        }
    }
}

pub fn svg(
    draw: impl FnOnce(&DrawingArea<SVGBackend, plotters::coord::Shift>) -> Result<()>,
    w: u32,
    h: u32,
) -> Result<String> {
    let mut s = String::new();
    {
        let root = SVGBackend::with_string(&mut s, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| anyhow::anyhow!("{e:?}"))?;
        draw(&root)?;
        root.present().map_err(|e| anyhow::anyhow!("{e:?}"))?;
    }
    Ok(s)
}

/// `yr` raised at the top so that a legend of `rows` entries in a top corner
/// sits above every point drawn: about 20 px a row plus its frame, of a
/// plotting area of about H − 100 px. A legend drawn over the data hid the
/// very bins where a mismatch shows.
pub fn room_for_legend(yr: (f64, f64), rows: usize) -> (f64, f64) {
    let share = ((20 * rows + 24) as f64 / (H - 100) as f64).min(0.6);
    (yr.0, yr.1 + (yr.1 - yr.0) * share / (1.0 - share))
}

/// Draws a chart's legend, framed on a white ground, in the corner `at`
/// (figures leave room for it with [`room_for_legend`]).
pub fn draw_legend<'a, DB: DrawingBackend + 'a, CT: plotters::coord::CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
    at: SeriesLabelPosition,
) -> Result<()> {
    chart
        .configure_series_labels()
        .position(at)
        .border_style(BLACK)
        .background_style(WHITE.mix(0.8))
        .draw()
        .map_err(|e| anyhow::anyhow!("plotting: {e:?}"))
}

/// `p!(plotters call)`: the call's error as an `anyhow` error, returned.
macro_rules! p {
    ($e:expr) => {
        $e.map_err(|e| anyhow::anyhow!("plotting: {e:?}"))?
    };
}
pub(crate) use p;

pub mod emulator;
pub mod png;

/// An axis label, "name [units]", or the name alone when no unit is known.
pub fn axis(name: &str, units: &str) -> String {
    if units.is_empty() {
        name.to_string()
    } else {
        format!("{name} [{units}]")
    }
}

pub fn range_of(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) =
        values.filter(|v| v.is_finite()).fold((f64::INFINITY, f64::NEG_INFINITY), |a, v| (a.0.min(v), a.1.max(v)));
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    let pad = 0.05 * (hi - lo).max(1e-9);
    (lo - pad, hi + pad)
}

fn quantile(v: &[f64], q: f64) -> f64 {
    crate::engine::calibrate::diagnostics::quantile(v, q)
}

/// Corner plot of the model parameters for several runs overlaid.
pub fn corner_plot(
    runs: &[&RunArtifacts],
    params: &[String],
    truth: &std::collections::BTreeMap<String, f64>,
    units: &dyn Fn(&str) -> String,
) -> Result<String> {
    let d = params.len();
    let cell = 240u32;
    let ranges: Vec<(f64, f64)> = params
        .iter()
        .map(|p| {
            let mut vals: Vec<f64> = Vec::new();
            for r in runs {
                if let Some(x) = r.param(p) {
                    vals.push(quantile(x, 0.005));
                    vals.push(quantile(x, 0.995));
                }
            }
            if let Some(t) = truth.get(p) {
                vals.push(*t);
            }
            range_of(vals.into_iter())
        })
        .collect();
    svg(
        |root| {
            let panels = root.split_evenly((d, d));
            for i in 0..d {
                for j in 0..d {
                    let area = &panels[i * d + j];
                    if j > i {
                        continue;
                    }
                    let (xr, yr) = (ranges[j], ranges[i]);
                    let xlabel = axis(&params[j], &units(&params[j]));
                    if i == j {
                        corner_marginal(area, runs, &params[i], xr, truth, &xlabel, i == 0)?;
                    } else {
                        let ylabel = axis(&params[i], &units(&params[i]));
                        let mut chart = p!(ChartBuilder::on(area)
                            .margin(6)
                            .x_label_area_size(34)
                            .y_label_area_size(40)
                            .build_cartesian_2d(xr.0..xr.1, yr.0..yr.1));
                        p!(chart
                            .configure_mesh()
                            .x_desc(xlabel.as_str())
                            .y_desc(ylabel.as_str())
                            .x_labels(5)
                            .y_labels(5)
                            .draw());
                        for r in runs {
                            let c = kernel_colour(&r.summary.kernel);
                            let (x, y) = (r.param(&params[j]).unwrap_or(&[]), r.param(&params[i]).unwrap_or(&[]));
                            let step = (x.len() / 1500).max(1);
                            p!(chart.draw_series((0..x.len()).step_by(step).map(|k| Circle::new(
                                (x[k], y[k]),
                                1,
                                c.mix(0.25).filled()
                            ))));
                        }
                        if let (Some(tx), Some(ty)) = (truth.get(&params[j]), truth.get(&params[i])) {
                            p!(chart.draw_series(DashedLineSeries::new(
                                vec![(*tx, yr.0), (*tx, yr.1)],
                                6,
                                4,
                                TRUTH.stroke_width(2)
                            )));
                            p!(chart.draw_series(DashedLineSeries::new(
                                vec![(xr.0, *ty), (xr.1, *ty)],
                                6,
                                4,
                                TRUTH.stroke_width(2)
                            )));
                        }
                    }
                }
            }
            Ok(())
        },
        cell * d as u32,
        cell * d as u32,
    )
}

type Area<'a> = DrawingArea<SVGBackend<'a>, plotters::coord::Shift>;

/// A corner plot's diagonal panel: each run's normalized histogram of
/// `param` with its median and 68% band, the prior's density and the truth.
fn corner_marginal(
    area: &Area,
    runs: &[&RunArtifacts],
    param: &str,
    xr: (f64, f64),
    truth: &std::collections::BTreeMap<String, f64>,
    xlabel: &str,
    legend: bool,
) -> Result<()> {
    let i = param;
    // Marginal: normalized histogram per run, median ± 68% band.
    let bins = 40;
    let width = (xr.1 - xr.0) / bins as f64;
    let mut hists = Vec::new();
    let mut ymax: f64 = 0.0;
    for r in runs {
        let x = r.param(i).unwrap_or(&[]);
        let mut h = vec![0.0; bins];
        for v in x {
            let b = ((v - xr.0) / width).floor();
            if b >= 0.0 && (b as usize) < bins {
                h[b as usize] += 1.0;
            }
        }
        let norm = x.len().max(1) as f64 * width;
        h.iter_mut().for_each(|c| *c /= norm);
        ymax = ymax.max(h.iter().cloned().fold(0.0, f64::max));
        hists.push(h);
    }
    let mut chart = p!(ChartBuilder::on(area)
        .margin(6)
        .x_label_area_size(34)
        .y_label_area_size(40)
        .build_cartesian_2d(xr.0..xr.1, 0.0..ymax * 1.15));
    p!(chart.configure_mesh().x_desc(xlabel).y_desc("density").x_labels(5).y_labels(4).draw());
    // The uniform prior's density, shaded (flat and low when the prior is wide).
    if let Some([lo, hi]) = runs.first().and_then(|r| r.summary.prior_bounds.get(i).copied()) {
        let dens = 1.0 / (hi - lo);
        let grey = RGBColor(160, 160, 160);
        p!(chart
            .draw_series(std::iter::once(Rectangle::new(
                [(lo.max(xr.0), 0.0), (hi.min(xr.1), dens.min(ymax * 1.15))],
                grey.mix(0.35).filled()
            )))
            .map(|s| s
                .label("prior")
                .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 14, y + 5)], grey.mix(0.5).filled()))));
    }
    for (r, h) in runs.iter().zip(&hists) {
        let c = kernel_colour(&r.summary.kernel);
        let x = r.param(i).unwrap_or(&[]);
        let (q16, q84) = (quantile(x, 0.16), quantile(x, 0.84));
        p!(chart.draw_series(std::iter::once(Rectangle::new([(q16, 0.0), (q84, ymax * 1.15)], c.mix(0.12).filled()))));
        let pts: Vec<(f64, f64)> =
            (0..bins).flat_map(|b| [(xr.0 + b as f64 * width, h[b]), (xr.0 + (b + 1) as f64 * width, h[b])]).collect();
        p!(chart.draw_series(LineSeries::new(pts, c.stroke_width(2))).map(|s| s
            .label(format!("kernel {}", r.summary.kernel))
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 14, y)], c.stroke_width(2)))));
        let med = quantile(x, 0.5);
        p!(chart
            .draw_series(std::iter::once(PathElement::new(vec![(med, 0.0), (med, ymax * 1.15)], c.stroke_width(1)))));
    }
    if let Some(t) = truth.get(i) {
        p!(chart
            .draw_series(DashedLineSeries::new(vec![(*t, 0.0), (*t, ymax * 1.15)], 6, 4, TRUTH.stroke_width(2)))
            .map(|s| s
                .label("truth")
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 14, y)], TRUTH.stroke_width(2)))));
    }
    if legend {
        draw_legend(&mut chart, SeriesLabelPosition::MiddleRight)?;
    }
    Ok(())
}

/// Data with error bars, model-alone and model+δ bands, for one observable.
pub fn prediction_plot(
    run: &RunArtifacts,
    observable: &str,
    x_units: &str,
    y_units: &str,
    title: &str,
) -> Result<String> {
    let x = run.pred_col(observable, "grid", "x");
    let cols = |p: &str| {
        ["q025", "q16", "median", "q84", "q975"].map(|q| run.pred_col(observable, "grid", &format!("{p}_{q}")))
    };
    let (model, md) = (cols("model"), cols("model_md"));
    let truth = run.pred_col(observable, "grid", "truth");
    let data: Vec<&Measurement> = run.data.iter().filter(|m| m.observable == observable).collect();
    let yr = range_of(
        model[0]
            .iter()
            .chain(&model[4])
            .chain(&md[0])
            .chain(&md[4])
            .chain(&truth)
            .cloned()
            .chain(data.iter().flat_map(|m| [m.value - m.error, m.value + m.error])),
    );
    let yr = room_for_legend(yr, 5);
    let xr = range_of(x.iter().cloned());
    let colour = kernel_colour(&run.summary.kernel);
    svg(
        |root| {
            let mut chart = p!(ChartBuilder::on(root)
                .caption(title, ("sans-serif", 16))
                .margin(8)
                .x_label_area_size(40)
                .y_label_area_size(56)
                .build_cartesian_2d(xr.0..xr.1, yr.0..yr.1));
            let (xd, yd) = (axis("x", x_units), axis(observable, y_units));
            p!(chart.configure_mesh().x_desc(xd.as_str()).y_desc(yd.as_str()).draw());
            let band = |lo: &[f64], hi: &[f64]| -> Vec<(f64, f64)> {
                x.iter().zip(lo).map(|(a, b)| (*a, *b)).chain(x.iter().zip(hi).rev().map(|(a, b)| (*a, *b))).collect()
            };
            let grey = RGBColor(150, 150, 150);
            p!(chart
                .draw_series(std::iter::once(Polygon::new(band(&model[0], &model[4]), grey.mix(0.25).filled())))
                .map(|s| s
                    .label("model alone, 95%")
                    .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 14, y + 5)], grey.mix(0.4).filled()))));
            if run.summary.kernel != "none" {
                p!(chart
                    .draw_series(std::iter::once(Polygon::new(band(&md[0], &md[4]), colour.mix(0.25).filled())))
                    .map(|s| s.label("model + δ, 95%").legend(move |(x, y)| Rectangle::new(
                        [(x, y - 5), (x + 14, y + 5)],
                        colour.mix(0.4).filled()
                    ))));
                p!(chart.draw_series(LineSeries::new(
                    x.iter().cloned().zip(md[2].iter().cloned()),
                    colour.stroke_width(2)
                )));
            }
            p!(chart
                .draw_series(LineSeries::new(x.iter().cloned().zip(model[2].iter().cloned()), BLACK.stroke_width(1)))
                .map(|s| s.label("model median").legend(|(x, y)| PathElement::new(vec![(x, y), (x + 14, y)], BLACK))));
            let true_curve: Vec<(f64, f64)> =
                x.iter().cloned().zip(truth.iter().cloned()).filter(|p| p.1.is_finite()).collect();
            if !true_curve.is_empty() {
                p!(chart.draw_series(DashedLineSeries::new(true_curve, 6, 4, TRUTH.stroke_width(2))).map(|s| s
                    .label("truth")
                    .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 14, y)], TRUTH.stroke_width(2)))));
            }
            p!(chart
                .draw_series(data.iter().map(|m| ErrorBar::new_vertical(
                    m.x,
                    m.value - m.error,
                    m.value,
                    m.value + m.error,
                    BLACK.filled(),
                    6
                )))
                .map(|s| s.label("data ± 1σ").legend(|(x, y)| Circle::new((x + 7, y), 3, BLACK.filled()))));
            draw_legend(&mut chart, SeriesLabelPosition::UpperRight)?;
            Ok(())
        },
        W,
        H,
    )
}

/// δ(x) posterior band for one observable, with the zero line.
pub fn delta_plot(run: &RunArtifacts, observable: &str, x_units: &str, y_units: &str) -> Result<String> {
    let x = run.pred_col(observable, "grid", "x");
    let q = ["q025", "median", "q975"].map(|c| run.pred_col(observable, "grid", &format!("delta_{c}")));
    let yr = room_for_legend(range_of(q[0].iter().chain(&q[2]).cloned().chain([0.0])), 3);
    let xr = range_of(x.iter().cloned());
    let colour = kernel_colour(&run.summary.kernel);
    svg(
        |root| {
            let title = format!("discrepancy δ(x): {observable}");
            let mut chart = p!(ChartBuilder::on(root)
                .caption(title.as_str(), ("sans-serif", 16))
                .margin(8)
                .x_label_area_size(40)
                .y_label_area_size(56)
                .build_cartesian_2d(xr.0..xr.1, yr.0..yr.1));
            let yd = axis("δ", y_units);
            let xd = axis("x", x_units);
            p!(chart.configure_mesh().x_desc(xd.as_str()).y_desc(yd.as_str()).draw());
            let poly: Vec<(f64, f64)> = x
                .iter()
                .cloned()
                .zip(q[0].iter().cloned())
                .chain(x.iter().cloned().zip(q[2].iter().cloned()).rev())
                .collect();
            p!(chart.draw_series(std::iter::once(Polygon::new(poly, colour.mix(0.3).filled()))).map(|s| s
                .label("δ 95% band")
                .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 14, y + 5)], colour.mix(0.4).filled()))));
            p!(chart
                .draw_series(LineSeries::new(x.iter().cloned().zip(q[1].iter().cloned()), colour.stroke_width(2)))
                .map(|s| s
                    .label("δ median")
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 14, y)], colour.stroke_width(2)))));
            p!(chart
                .draw_series(DashedLineSeries::new(vec![(xr.0, 0.0), (xr.1, 0.0)], 6, 4, BLACK.stroke_width(1)))
                .map(|s| s.label("δ = 0").legend(|(x, y)| PathElement::new(vec![(x, y), (x + 14, y)], BLACK))));
            draw_legend(&mut chart, SeriesLabelPosition::UpperLeft)?;
            Ok(())
        },
        W,
        H,
    )
}

/// Heat map: observable × x, coloured by posterior-mean δ/σ.
pub fn mismatch_map(d: &Diagnosis, x_units: &str) -> Result<String> {
    let rows = &d.mismatch;
    let max = rows.iter().flat_map(|m| m.map.iter().map(|p| p.1.abs())).fold(1.0, f64::max);
    svg(
        |root| {
            let (main, bar) = root.split_horizontally(W + 40);
            let n = rows.len();
            let xr = range_of(rows.iter().flat_map(|m| m.map.iter().map(|p| p.0)));
            let mut chart = p!(ChartBuilder::on(&main)
                .caption("mismatch map: posterior-mean δ / σ", ("sans-serif", 16))
                .margin(8)
                .x_label_area_size(40)
                .y_label_area_size(110)
                .build_cartesian_2d(xr.0..xr.1, 0.0..n as f64));
            let names: Vec<String> = rows.iter().map(|m| m.observable.clone()).collect();
            let xd = axis("x", x_units);
            p!(chart
                .configure_mesh()
                .disable_mesh()
                .x_desc(xd.as_str())
                .y_desc("observable")
                .y_labels(n * 2 + 1)
                .y_label_formatter(&|v| category_label(&names, *v))
                .draw());
            for (k, m) in rows.iter().enumerate() {
                let xs: Vec<f64> = m.map.iter().map(|p| p.0).collect();
                for (i, &(x, z)) in m.map.iter().enumerate() {
                    let left =
                        if i == 0 { x - (xs.get(1).unwrap_or(&(x + 0.1)) - x) / 2.0 } else { (x + xs[i - 1]) / 2.0 };
                    let right = if i + 1 == xs.len() { x + (x - left) } else { (x + xs[i + 1]) / 2.0 };
                    p!(chart.draw_series(std::iter::once(Rectangle::new(
                        [(left, k as f64 + 0.05), (right, k as f64 + 0.95)],
                        diverging(z / max).filled()
                    ))));
                }
            }
            // Colour bar.
            let mut cb = p!(ChartBuilder::on(&bar)
                .margin(8)
                .margin_top(40)
                .margin_right(30)
                .y_label_area_size(75)
                .build_cartesian_2d(0.0..1.0, -max..max));
            p!(cb
                .configure_mesh()
                .disable_x_axis()
                .disable_mesh()
                .y_labels(5)
                .y_label_style(("sans-serif", 15))
                .axis_desc_style(("sans-serif", 15))
                .y_desc("δ/σ")
                .draw());
            p!(cb.draw_series((0..100).map(|i| {
                let v0 = -max + 2.0 * max * i as f64 / 100.0;
                let v1 = v0 + 2.0 * max / 100.0;
                Rectangle::new([(0.0, v0), (1.0, v1)], diverging(v0 / max).filled())
            })));
            Ok(())
        },
        W + 200,
        60 + 70 * rows.len() as u32 + 60,
    )
}

/// Axis label for categories drawn at k + 0.5 on a numeric axis; blank elsewhere.
fn category_label(names: &[String], v: f64) -> String {
    let k = v.floor() as usize;
    if (v - k as f64 - 0.5).abs() < 0.26 && k < names.len() {
        names[k].clone()
    } else {
        String::new()
    }
}

/// Blue (negative) – white – red (positive).
fn diverging(t: f64) -> RGBColor {
    let t = t.clamp(-1.0, 1.0);
    if t >= 0.0 {
        RGBColor(255, (255.0 * (1.0 - t)) as u8, (255.0 * (1.0 - t)) as u8)
    } else {
        RGBColor((255.0 * (1.0 + t)) as u8, (255.0 * (1.0 + t)) as u8, 255)
    }
}

/// Bar chart of each model's log evidence relative to the leader's (the
/// best candidate or the MD fit), one horizontal bar per model, best on top.
/// The differences that decide a verdict are a few units while models that
/// miss sit hundreds below, so the axis stops at [`BF_AXIS_FLOOR`] and a
/// longer bar is cut there with its value written on it. The dashed line is
/// the decisive margin: a model to its right is not excluded by the leader.
pub fn bayes_factor_chart(d: &Diagnosis) -> Result<String> {
    let mut rows: Vec<(String, f64, RGBColor)> = d
        .candidates
        .iter()
        .map(|c| {
            let chosen = c.name == d.verdict.best || d.verdict.standing.contains(&c.name);
            let colour = if chosen { RGBColor(205, 120, 20) } else { RGBColor(110, 110, 160) };
            (c.name.clone(), c.log_bayes_factor, colour)
        })
        .collect();
    rows.push(("model + MD".into(), d.md_log_evidence - d.base_log_evidence, RGBColor(30, 150, 60)));
    rows.push(("model, no MD".into(), 0.0, RGBColor(200, 60, 50)));
    rows.retain(|r| r.1.is_finite());
    rows.sort_by(|a, b| b.1.total_cmp(&a.1));
    let leader = rows.first().map(|r| r.1).unwrap_or(0.0);
    let margin = crate::engine::diagnose::DiagnoseSettings::default().strong_log_bf;
    let floor = rows.iter().map(|r| r.1 - leader).fold(0.0f64, f64::min).max(BF_AXIS_FLOOR).min(-3.0 * margin);
    let names: Vec<String> = rows.iter().map(|r| r.0.clone()).collect();
    let n = names.len();
    // Room for the longest name at about 7 px a character, and 26 px a bar.
    let label_width = 7 * names.iter().map(|s| s.chars().count()).max().unwrap_or(8) as u32 + 16;
    let height = H.max(26 * n as u32 + 90);
    svg(
        |root| {
            let mut chart = p!(ChartBuilder::on(root)
                .caption(
                    format!("log Bayes factor against the leader (dashed: the decisive margin, {margin})"),
                    ("sans-serif", 15)
                )
                .margin(8)
                .x_label_area_size(40)
                .y_label_area_size(label_width)
                .build_cartesian_2d(floor * 1.02..0.5, 0.0..n as f64));
            // Row k from the top is category n - 1 - k on the axis.
            let row = |v: f64| category_label(&names, n as f64 - v);
            p!(chart
                .configure_mesh()
                .disable_y_mesh()
                .x_desc("log Z − log Z(leader)")
                .y_desc("model")
                .y_labels(2 * n + 1)
                .y_label_formatter(&|v| row(*v))
                .draw());
            for (k, (_, value, colour)) in rows.iter().enumerate() {
                let top = (n - k) as f64;
                let relative = value - leader;
                let end = relative.max(floor);
                p!(chart.draw_series(std::iter::once(Rectangle::new(
                    [(end, top - 0.15), (0.0, top - 0.85)],
                    colour.filled()
                ))));
                if k == 0 {
                    // The leader's bar has no length: name it and its own Bayes factor.
                    p!(chart.draw_series(std::iter::once(Rectangle::new(
                        [(floor * 0.004, top - 0.15), (0.0, top - 0.85)],
                        colour.filled()
                    ))));
                    p!(chart.draw_series(std::iter::once(Text::new(
                        format!("the leader: log BF {value:.1} against the model without MD"),
                        (floor * 0.99, top - 0.38),
                        ("sans-serif", 12).into_font()
                    ))));
                }
                if relative < floor {
                    p!(chart.draw_series(std::iter::once(Text::new(
                        format!("{relative:.1}"),
                        (floor * 0.99, top - 0.38),
                        ("sans-serif", 12).into_font().color(&WHITE)
                    ))));
                }
            }
            p!(chart.draw_series(DashedLineSeries::new(
                vec![(-margin, 0.0), (-margin, n as f64)],
                6,
                4,
                BLACK.stroke_width(1)
            )));
            Ok(())
        },
        W + 100 + label_width,
        height,
    )
}

/// How far below the leader the Bayes-factor chart's axis reaches.
const BF_AXIS_FLOOR: f64 = -40.0;

pub fn html_escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;")
}

/// Finds calibration folders (with summary.json) in `dirs` and one level below.
fn find_runs(dirs: &[PathBuf]) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for d in dirs {
        if d.join("summary.json").exists() {
            out.push(d.clone());
        }
        if let Ok(rd) = std::fs::read_dir(d) {
            let mut subs: Vec<PathBuf> =
                rd.filter_map(|e| e.ok().map(|e| e.path())).filter(|p| p.join("summary.json").exists()).collect();
            subs.sort();
            out.extend(subs);
        }
    }
    out
}

fn figure(html: &mut String, caption: &str, svg: &str) {
    html.push_str(&format!("<figure>{svg}<figcaption>{}</figcaption></figure>\n", html_escape(caption)));
}

/// Figures a system adds to reports of its own calibrations; the report
/// itself knows no system.
pub trait SystemFigures: Sync {
    /// Whether `run` is one of this system's calibrations.
    fn claims(&self, run: &RunArtifacts) -> bool;
    /// Figures (caption, SVG) after the corner plot of one observable set.
    fn posterior_figures(
        &self,
        _group: &[&RunArtifacts],
        _truth: &BTreeMap<String, f64>,
    ) -> Result<Vec<(String, String)>> {
        Ok(Vec::new())
    }
    /// One observable's predictions, instead of the generic bands.
    fn prediction_figure(&self, _run: &RunArtifacts, _observable: &str) -> Result<Option<(String, String)>> {
        Ok(None)
    }
}

const HEAD: &str = "<style>body{font-family:sans-serif;max-width:1250px;margin:2em auto;color:#222} figure{display:inline-block;margin:8px;vertical-align:top} figcaption{font-size:13px;color:#444;max-width:560px} table{border-collapse:collapse;font-size:13px} td,th{border:1px solid #bbb;padding:3px 6px} .verdict{font-size:17px;background:#f4f4e8;padding:10px;border-left:4px solid #c80}</style>";

/// Builds `report.html` from run folders; returns its text. `systems` add
/// their own figures to the runs they claim.
pub fn build(dirs: &[PathBuf], title: &str, systems: &[&dyn SystemFigures]) -> Result<String> {
    let runs: Vec<RunArtifacts> = find_runs(dirs).iter().map(|d| RunArtifacts::load(d)).collect::<Result<_>>()?;
    let mut html = format!(
        "<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>{0}</title>{HEAD}</head><body><h1>{0}</h1>\n",
        html_escape(title)
    );
    // Diagnosis first: it is the story.
    for d in dirs {
        let p = d.join("diagnosis.json");
        if p.exists() {
            let diag: Diagnosis = serde_json::from_str(&std::fs::read_to_string(&p)?)
                .with_context(|| format!("parsing {}", p.display()))?;
            diagnosis_section(&mut html, &diag, &runs)?;
        }
    }
    posterior_sections(&mut html, &runs, systems)?;
    emulator_section(&mut html, dirs)?;
    if let Some(r) = runs.first() {
        let p = &r.summary.provenance;
        html.push_str(&format!(
            "<p style=\"font-size:12px;color:#666\">mdpipe {} · config {} · seed {}</p>",
            p.mdpipe_version,
            &p.config_hash.get(..12).unwrap_or(""),
            p.seed
        ));
    }
    // Records each figure's rendered size on the page, so a headless browser
    // can check that every figure actually laid out (tests/it/diagnose.rs).
    html.push_str("<script>window.addEventListener('load',function(){var s=[];document.querySelectorAll('figure svg').forEach(function(e){var r=e.getBoundingClientRect();s.push(Math.round(r.width)+'x'+Math.round(r.height));});document.body.setAttribute('data-figure-sizes',s.join(','));});</script>\n");
    html.push_str("</body></html>\n");
    Ok(html)
}

/// The verdict, the mismatch map, the candidates and the repair's before/after.
fn diagnosis_section(html: &mut String, diag: &Diagnosis, runs: &[RunArtifacts]) -> Result<()> {
    let units = runs.first().map(|r| r.summary.units.clone()).unwrap_or_default();
    html.push_str("<h2>Diagnosis</h2>\n");
    html.push_str(&format!(
        "<p class=\"verdict\"><b>{}</b> ({}): {}</p>\n",
        html_escape(&diag.verdict.best),
        html_escape(&diag.verdict.confidence_phrase()),
        html_escape(&diag.verdict.statement)
    ));
    figure(
        html,
        "Where the model misses: posterior-mean discrepancy of the MD fit at each measurement, in units of its error.",
        &mismatch_map(diag, &units.x)?,
    );
    figure(
        html,
        "Every model's SMC evidence against the leader's: candidates (the verdict's in orange), the MD fit (green) and the model without MD (red). Bars beyond the axis are cut and carry their value.",
        &bayes_factor_chart(diag)?,
    );
    // For emulated models, how much of each fit's predictive variance is the emulator's own.
    let emulated = diag.candidates.iter().any(|c| c.emulator_share > 0.0);
    let share_head = if emulated { "<th>emulator share of variance (worst observable)</th>" } else { "" };
    html.push_str(&format!("<table><tr><th>candidate</th><th>log BF</th><th>χ²/dof</th>{share_head}<th>parameters (median [95%])</th></tr>\n"));
    for c in &diag.candidates {
        let share = if emulated {
            format!("<td>{:.0}% {}</td>", 100.0 * c.emulator_share, c.emulator_share_observable)
        } else {
            String::new()
        };
        html.push_str(&format!(
            "<tr><td>{}</td><td>{:.1} ± {:.1}</td><td>{:.2}</td>{share}<td>{}</td></tr>\n",
            c.name,
            c.log_bayes_factor,
            c.log_bayes_factor_err,
            c.chi2_per_dof,
            intervals(&c.parameters)
        ));
    }
    html.push_str("</table>\n");
    if let Some(imp) = &diag.improvement {
        html.push_str("<h3>Before and after the repair</h3><p>χ²/dof is of the model part η alone: for a fit with δ it is what δ had to absorb, not that fit's misfit.</p><table><tr><th>fit</th><th>χ²/dof of η</th><th>log Z</th><th>max |δ|/σ</th><th>parameters</th></tr>\n");
        for f in imp.before.iter().chain(&imp.after) {
            let dmax = f.delta_max_sigma.values().cloned().fold(0.0, f64::max);
            html.push_str(&format!(
                "<tr><td>{}</td><td>{:.2}</td><td>{:.2} ± {:.2}</td><td>{:.1}</td><td>{}</td></tr>\n",
                f.label,
                f.chi2_per_dof,
                f.log_evidence,
                f.log_evidence_err,
                dmax,
                intervals(&f.parameters)
            ));
        }
        html.push_str("</table>\n");
        let narrowing: Vec<String> = imp
            .interval_narrowing
            .iter()
            .map(|(n, r)| {
                let change = if *r >= 1.0 { format!("{r:.2}× narrower") } else { format!("{:.2}× wider", 1.0 / r) };
                match imp.information_limit.get(n) {
                    Some(l) => format!("{n}: {change} (Cramér–Rao limit of these data {l:.2}×)"),
                    None => format!("{n}: {change}"),
                }
            })
            .collect();
        html.push_str(&format!(
            "<p>95% intervals of the repaired model against model + δ: {}.</p>\n",
            narrowing.join("; ")
        ));
    }
    for (name, label) in [("base_md", "before: model + δ"), ("repaired_md", "after: repaired model + δ")] {
        let Some(run) = runs.iter().find(|r| r.dir.file_name().map(|f| f == name).unwrap_or(false)) else { continue };
        let u = &run.summary.units;
        for obs in &run.summary.observables {
            figure(
                html,
                &format!("{label}: δ({obs}) with its 95% band; after the repair it should hug zero."),
                &delta_plot(run, obs, &u.x, u.observable(obs))?,
            );
        }
        for obs in &run.summary.observables {
            figure(
                html,
                &format!("{label}: {obs}, data and predictions (the grid extends beyond the data)."),
                &prediction_plot(run, obs, &u.x, u.observable(obs), &format!("{label}: {obs}"))?,
            );
        }
    }
    Ok(())
}

/// "name = median [q025, q975], …".
fn intervals(parameters: &BTreeMap<String, ParamSummary>) -> String {
    parameters
        .iter()
        .map(|(n, p)| format!("{n} = {:.3} [{:.3}, {:.3}]", p.median, p.q025, p.q975))
        .collect::<Vec<_>>()
        .join(", ")
}

/// Per observable set: the corner plot of every kernel's run, the system's
/// own figures, a table, and (for the largest set) each run's predictions.
fn posterior_sections(html: &mut String, runs: &[RunArtifacts], systems: &[&dyn SystemFigures]) -> Result<()> {
    let mut sets: Vec<Vec<String>> = Vec::new();
    for r in runs {
        if !sets.contains(&r.summary.observables) {
            sets.push(r.summary.observables.clone());
        }
    }
    if !runs.is_empty() {
        html.push_str("<h2>Posteriors</h2>\n");
    }
    let largest = sets.iter().map(|s| s.len()).max().unwrap_or(0);
    // Candidate-augmented fits have extra parameters; diagnose shows them above.
    let is_candidate = |r: &RunArtifacts| {
        r.dir.file_name().and_then(|f| f.to_str()).is_some_and(|f| f.starts_with("candidate_") || f == "repaired_md")
    };
    for set in &sets {
        let group: Vec<&RunArtifacts> =
            runs.iter().filter(|r| &r.summary.observables == set && !is_candidate(r)).collect();
        if group.is_empty() {
            continue;
        }
        let system = systems.iter().find(|s| s.claims(group[0]));
        let theta: Vec<String> =
            group[0].summary.parameter_order.iter().filter(|n| !n.contains('.')).cloned().collect();
        let truth = group[0].summary.truth.clone();
        let units = group[0].summary.units.clone();
        let kernels: Vec<&str> = group.iter().map(|r| r.summary.kernel.as_str()).collect();
        figure(
            html,
            &format!("Observables {}: posteriors for kernels {} (no MD red, Kernel I blue, Kernel II green; truth dashed grey; coloured bands: median ± 68%; grey: the uniform prior's density).", set.join(", "), kernels.join(", ")),
            &corner_plot(&group, &theta, &truth, &|p| units.parameter(p).to_string())?,
        );
        for (caption, svg) in system.map(|s| s.posterior_figures(&group, &truth)).transpose()?.unwrap_or_default() {
            figure(html, &caption, &svg);
        }
        posterior_table(html, &group, &theta);
        if set.len() == largest {
            for r in &group {
                for obs in set {
                    let own = system.map(|s| s.prediction_figure(r, obs)).transpose()?.flatten();
                    let (caption, svg) = match own {
                        Some(f) => f,
                        None => (
                            format!(
                                "Kernel {}: {obs}, data with 1σ errors and 95% posterior-predictive bands.",
                                r.summary.kernel
                            ),
                            prediction_plot(
                                r,
                                obs,
                                &r.summary.units.x,
                                r.summary.units.observable(obs),
                                &format!("kernel {}: {obs}", r.summary.kernel),
                            )?,
                        ),
                    };
                    figure(html, &caption, &svg);
                }
            }
        }
    }
    Ok(())
}

fn posterior_table(html: &mut String, group: &[&RunArtifacts], theta: &[String]) {
    html.push_str("<table><tr><th>kernel</th>");
    for t in theta {
        html.push_str(&format!("<th>{t} median [95%]</th>"));
    }
    html.push_str("<th>log Z</th><th>converged</th></tr>\n");
    for r in group {
        html.push_str(&format!("<tr><td>{}</td>", r.summary.kernel));
        for t in theta {
            let p = &r.summary.parameters[t];
            html.push_str(&format!("<td>{:.3} [{:.3}, {:.3}]</td>", p.median, p.q025, p.q975));
        }
        let z = r
            .summary
            .log_evidence
            .map(|z| format!("{z:.2} ± {:.2}", r.summary.log_evidence_err.unwrap_or(f64::NAN)))
            .unwrap_or_else(|| "–".into());
        html.push_str(&format!(
            "<td>{z}</td><td>{}</td></tr>\n",
            if r.summary.diagnostics.converged { "yes" } else { "NO" }
        ));
    }
    html.push_str("</table>\n");
}

/// Parity plots and z-score histograms for every emulator folder (with
/// `validation_parity.parquet`) in `dirs` or one level below.
fn emulator_section(html: &mut String, dirs: &[PathBuf]) -> Result<()> {
    let mut found = Vec::new();
    for d in dirs {
        let mut candidates = vec![d.clone()];
        if let Ok(rd) = std::fs::read_dir(d) {
            let mut subs: Vec<PathBuf> = rd.filter_map(|e| e.ok().map(|e| e.path())).collect();
            subs.sort();
            candidates.extend(subs);
        }
        found.extend(candidates.into_iter().filter(|c| c.join("validation_parity.parquet").exists()));
    }
    for dir in found {
        let rows = emulator::load_parity(&dir.join("validation_parity.parquet"))?;
        html.push_str(&format!("<h2>Emulator validation: {}</h2>\n", html_escape(&dir.display().to_string())));
        let mut sets: Vec<String> = Vec::new();
        for r in &rows {
            if !sets.contains(&r.set) {
                sets.push(r.set.clone());
            }
        }
        for set in &sets {
            let subset: Vec<&emulator::ParityRow> = rows.iter().filter(|r| &r.set == set).collect();
            figure(
                html,
                &format!("{set}: z-scores of every output; a calibrated emulator follows N(0, 1)."),
                &emulator::z_histogram(&subset, set)?,
            );
        }
        // Parity per observable, on the held-out design if there is one.
        let set = if sets.iter().any(|s| s == "holdout") {
            "holdout".to_string()
        } else {
            sets.first().cloned().unwrap_or_default()
        };
        let mut observables: Vec<String> = Vec::new();
        for r in rows.iter().filter(|r| r.set == set) {
            if !observables.contains(&r.observable) {
                observables.push(r.observable.clone());
            }
        }
        for obs in &observables {
            let subset: Vec<&emulator::ParityRow> =
                rows.iter().filter(|r| r.set == set && &r.observable == obs).collect();
            figure(
                html,
                &format!("{set}: emulated against simulated {obs}, every pT bin and design point."),
                &emulator::parity_plot(&subset, obs)?,
            );
        }
    }
    Ok(())
}

pub fn write(dirs: &[PathBuf], out: &Path, title: &str, systems: &[&dyn SystemFigures]) -> Result<()> {
    let html = build(dirs, title, systems)?;
    artifacts::write_text_atomic(out, &html)
}
