//! Heavy-ion figures: η/s(T) posterior bands with the ε_sw posterior as an
//! inset, and per-pT-bin prediction boxes against the data.

use crate::engine::calibrate::sampler::diagnostics::quantile_sorted;
use crate::engine::report::{kernel_colour, p, range_of, svg, RunArtifacts, SystemFigures, H, TRUTH, W};
use crate::systems::heavy_ion::EtaOverS;
use anyhow::Result;
use plotters::prelude::*;
use std::collections::BTreeMap;

/// A heavy-ion calibration: its parameters include the switching energy density.
pub fn is_heavy_ion(run: &RunArtifacts) -> bool {
    run.names.iter().any(|n| n == "e_sw")
}

/// η/s(T) from named parameters: `eta_s`, or the four kink parameters.
pub fn eta_s_from(get: &dyn Fn(&str) -> Option<f64>) -> Option<EtaOverS> {
    if let Some(v) = get("eta_s") {
        return Some(EtaOverS::Constant(v));
    }
    Some(EtaOverS::Kink {
        t_kink: get("T_kink")?,
        a_low: get("a_low")?,
        a_high: get("a_high")?,
        eta_s_kink: get("eta_s_kink")?,
    })
}

const T_MIN: f64 = 0.10;
const T_MAX: f64 = 0.35;
const T_POINTS: usize = 51;

/// Per-T quantiles (q025, median, q975) of η/s(T) over a run's posterior draws.
pub fn eta_s_band(run: &RunArtifacts) -> Option<Vec<(f64, f64, f64, f64)>> {
    let n = run.draws.first()?.len();
    let step = (n / 2000).max(1);
    let curves: Vec<EtaOverS> =
        (0..n).step_by(step).filter_map(|i| eta_s_from(&|p: &str| run.param(p).map(|d| d[i]))).collect();
    if curves.is_empty() {
        return None;
    }
    Some(
        (0..T_POINTS)
            .map(|k| {
                let t = T_MIN + (T_MAX - T_MIN) * k as f64 / (T_POINTS - 1) as f64;
                let mut v: Vec<f64> = curves.iter().map(|c| c.at(t)).collect();
                v.sort_by(|a, b| a.total_cmp(b));
                (t, quantile_sorted(&v, 0.025), quantile_sorted(&v, 0.5), quantile_sorted(&v, 0.975))
            })
            .collect(),
    )
}

/// η/s(T) medians and 95% bands of several runs, the truth dashed, and the
/// ε_sw posteriors as an inset.
pub fn eta_s_plot(runs: &[&RunArtifacts], truth: &BTreeMap<String, f64>, title: &str) -> Result<String> {
    let bands: Vec<(&RunArtifacts, Vec<(f64, f64, f64, f64)>)> =
        runs.iter().filter_map(|r| eta_s_band(r).map(|b| (*r, b))).collect();
    let true_curve = eta_s_from(&|p: &str| truth.get(p).copied());
    let yr = range_of(
        bands
            .iter()
            .flat_map(|(_, b)| b.iter().flat_map(|p| [p.1, p.3]))
            .chain(true_curve.map(|c| c.at(T_MIN)))
            .chain([0.0]),
    );
    svg(
        |root| {
            let mut chart = p!(ChartBuilder::on(root)
                .caption(title, ("sans-serif", 16))
                .margin(8)
                .x_label_area_size(40)
                .y_label_area_size(56)
                .build_cartesian_2d(T_MIN..T_MAX, 0.0..yr.1));
            p!(chart.configure_mesh().x_desc("T [GeV]").y_desc("η/s").draw());
            for (run, band) in &bands {
                let colour = kernel_colour(&run.summary.kernel);
                let poly: Vec<(f64, f64)> =
                    band.iter().map(|p| (p.0, p.1)).chain(band.iter().rev().map(|p| (p.0, p.3))).collect();
                p!(chart.draw_series(std::iter::once(Polygon::new(poly, colour.mix(0.2).filled()))));
                let kernel = if run.summary.kernel == "none" {
                    "no MD".to_string()
                } else {
                    format!("Kernel {}", run.summary.kernel)
                };
                let folder = run.dir.file_name().map(|f| f.to_string_lossy().into_owned()).unwrap_or_default();
                let label = format!("{kernel} ({folder})");
                p!(chart.draw_series(LineSeries::new(band.iter().map(|p| (p.0, p.2)), colour.stroke_width(2))).map(
                    |s| s
                        .label(format!("{label}: median, 95%"))
                        .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 14, y + 5)], colour.mix(0.5).filled()))
                ));
            }
            if let Some(c) = true_curve {
                let pts: Vec<(f64, f64)> = (0..T_POINTS)
                    .map(|k| T_MIN + (T_MAX - T_MIN) * k as f64 / (T_POINTS - 1) as f64)
                    .map(|t| (t, c.at(t)))
                    .collect();
                p!(chart
                    .draw_series(DashedLineSeries::new(pts, 6, 4, TRUTH.stroke_width(2)))
                    .map(|s| s.label("truth").legend(|(x, y)| PathElement::new(vec![(x, y), (x + 14, y)], TRUTH))));
            }
            crate::engine::report::draw_legend(&mut chart, SeriesLabelPosition::UpperLeft)?;

            // Inset: ε_sw posteriors as normalised histograms.
            let inset = root
                .clone()
                .shrink(((W as f64 * 0.55) as u32, 40), ((W as f64 * 0.42) as u32, (H as f64 * 0.42) as u32));
            let draws: Vec<(&RunArtifacts, &[f64])> =
                bands.iter().filter_map(|(r, _)| r.param("e_sw").map(|d| (*r, d))).collect();
            if draws.is_empty() {
                return Ok(());
            }
            let xr = range_of(draws.iter().flat_map(|(_, d)| d.iter().copied()).chain(truth.get("e_sw").copied()));
            let bins = 30;
            let width = (xr.1 - xr.0) / bins as f64;
            let hists: Vec<(RGBColor, Vec<f64>)> = draws
                .iter()
                .map(|(r, d)| {
                    let mut h = vec![0.0; bins];
                    for v in d.iter() {
                        let k = (((v - xr.0) / width) as usize).min(bins - 1);
                        h[k] += 1.0 / (d.len() as f64 * width);
                    }
                    (kernel_colour(&r.summary.kernel), h)
                })
                .collect();
            let top = hists.iter().flat_map(|(_, h)| h.iter().copied()).fold(0.0, f64::max) * 1.1;
            p!(inset.fill(&WHITE));
            let mut small = p!(ChartBuilder::on(&inset)
                .margin(4)
                .x_label_area_size(30)
                .y_label_area_size(10)
                .build_cartesian_2d(xr.0..xr.1, 0.0..top.max(1e-9)));
            p!(small
                .configure_mesh()
                .disable_mesh()
                .y_labels(0)
                .x_labels(4)
                .x_desc("ε_sw [GeV/fm³]")
                .label_style(("sans-serif", 10))
                .draw());
            for (colour, h) in &hists {
                let steps: Vec<(f64, f64)> = h
                    .iter()
                    .enumerate()
                    .flat_map(|(k, v)| [(xr.0 + k as f64 * width, *v), (xr.0 + (k + 1) as f64 * width, *v)])
                    .collect();
                p!(small.draw_series(LineSeries::new(steps, colour.stroke_width(2))));
            }
            if let Some(t) = truth.get("e_sw") {
                p!(small.draw_series(DashedLineSeries::new(vec![(*t, 0.0), (*t, top)], 4, 3, TRUTH.stroke_width(2))));
            }
            Ok(())
        },
        W,
        H,
    )
}

/// Per-pT-bin boxes of the posterior predictions (model + δ: 68% and 95%;
/// model alone: 95% outline) against the data. Spectra are shown as ratios to
/// the data, since they fall by orders of magnitude over 0–2 GeV.
pub fn prediction_boxes(run: &RunArtifacts, observable: &str, title: &str) -> Result<String> {
    let x = run.pred_col(observable, "data", "x");
    let q = |p: &str, k: &str| run.pred_col(observable, "data", &format!("{p}_{k}"));
    let data: Vec<&crate::base::artifacts::Measurement> =
        run.data.iter().filter(|m| m.observable == observable).collect();
    let ratio = observable.ends_with("spectrum");
    let scale = |i: usize| -> f64 {
        if ratio {
            data.iter().find(|m| (m.x - x[i]).abs() < 1e-9).map(|m| m.value).unwrap_or(f64::NAN)
        } else {
            1.0
        }
    };
    let (m025, m975) = (q("model", "q025"), q("model", "q975"));
    let (d025, d16, d50, d84, d975) = (
        q("model_md", "q025"),
        q("model_md", "q16"),
        q("model_md", "median"),
        q("model_md", "q84"),
        q("model_md", "q975"),
    );
    let s: Vec<f64> = (0..x.len()).map(scale).collect();
    let truth = run.pred_col(observable, "data", "truth");
    let yr =
        range_of((0..x.len()).flat_map(|i| [m025[i] / s[i], m975[i] / s[i], d025[i] / s[i], d975[i] / s[i]]).chain(
            data.iter().flat_map(|m| {
                let k = if ratio { m.value } else { 1.0 };
                [(m.value - m.error) / k, (m.value + m.error) / k]
            }),
        ));
    let yr = crate::engine::report::room_for_legend(yr, 5);
    let half = 0.4 * x.windows(2).map(|w| (w[1] - w[0]).abs()).fold(f64::INFINITY, f64::min).min(0.2);
    let xr = range_of(x.iter().flat_map(|v| [v - half, v + half]));
    let colour = kernel_colour(&run.summary.kernel);
    let md = run.summary.kernel != "none";
    svg(
        |root| {
            let mut chart = p!(ChartBuilder::on(root)
                .caption(title, ("sans-serif", 16))
                .margin(8)
                .x_label_area_size(40)
                .y_label_area_size(60)
                .build_cartesian_2d(xr.0..xr.1, yr.0..yr.1));
            let yd = if ratio { format!("{observable} / data") } else { observable.to_string() };
            p!(chart.configure_mesh().x_desc("pT [GeV]").y_desc(yd.as_str()).draw());
            let grey = RGBColor(110, 110, 110);
            p!(chart
                .draw_series((0..x.len()).map(|i| Rectangle::new(
                    [(x[i] - half, m025[i] / s[i]), (x[i] + half, m975[i] / s[i])],
                    grey.stroke_width(1)
                )))
                .map(|s| s
                    .label("model alone, 95%")
                    .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 14, y + 5)], grey.stroke_width(1)))));
            if md {
                p!(chart
                    .draw_series((0..x.len()).map(|i| Rectangle::new(
                        [(x[i] - half, d025[i] / s[i]), (x[i] + half, d975[i] / s[i])],
                        colour.mix(0.2).filled()
                    )))
                    .map(|s| s.label("model + δ, 95%").legend(move |(x, y)| Rectangle::new(
                        [(x, y - 5), (x + 14, y + 5)],
                        colour.mix(0.3).filled()
                    ))));
                p!(chart
                    .draw_series((0..x.len()).map(|i| Rectangle::new(
                        [(x[i] - half, d16[i] / s[i]), (x[i] + half, d84[i] / s[i])],
                        colour.mix(0.45).filled()
                    )))
                    .map(|s| s.label("model + δ, 68%").legend(move |(x, y)| Rectangle::new(
                        [(x, y - 5), (x + 14, y + 5)],
                        colour.mix(0.6).filled()
                    ))));
                p!(chart.draw_series((0..x.len()).map(|i| PathElement::new(
                    vec![(x[i] - half, d50[i] / s[i]), (x[i] + half, d50[i] / s[i])],
                    colour.stroke_width(2)
                ))));
            }
            if truth.iter().any(|t| t.is_finite()) {
                p!(chart
                    .draw_series((0..x.len()).filter(|&i| truth[i].is_finite()).map(|i| PathElement::new(
                        vec![(x[i] - half, truth[i] / s[i]), (x[i] + half, truth[i] / s[i])],
                        TRUTH.stroke_width(2)
                    )))
                    .map(|s| s
                        .label("truth")
                        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 14, y)], TRUTH.stroke_width(2)))));
            }
            p!(chart
                .draw_series(data.iter().map(|m| {
                    let k = if ratio { m.value } else { 1.0 };
                    ErrorBar::new_vertical(
                        m.x,
                        (m.value - m.error) / k,
                        m.value / k,
                        (m.value + m.error) / k,
                        BLACK.filled(),
                        6,
                    )
                }))
                .map(|s| s.label("data ± 1σ").legend(|(x, y)| Circle::new((x + 7, y), 3, BLACK.filled()))));
            crate::engine::report::draw_legend(&mut chart, SeriesLabelPosition::UpperRight)?;
            Ok(())
        },
        W,
        H,
    )
}

/// The heavy-ion figures in reports: η/s(T) bands beside each corner plot,
/// and per-pT-bin boxes for the predictions.
pub struct HeavyIonFigures;

impl SystemFigures for HeavyIonFigures {
    fn claims(&self, run: &RunArtifacts) -> bool {
        is_heavy_ion(run)
    }

    fn posterior_figures(
        &self,
        group: &[&RunArtifacts],
        truth: &BTreeMap<String, f64>,
    ) -> Result<Vec<(String, String)>> {
        let set = group.first().map(|r| r.summary.observables.join(", ")).unwrap_or_default();
        Ok(vec![(format!("Observables {set}: η/s(T) posterior medians and 95% bands (truth dashed grey); inset: the ε_sw posteriors."), eta_s_plot(group, truth, "η/s(T) and ε_sw")?)])
    }

    fn prediction_figure(&self, run: &RunArtifacts, observable: &str) -> Result<Option<(String, String)>> {
        let kernel = &run.summary.kernel;
        let caption = format!("Kernel {kernel}: {observable} per pT bin: posterior-predictive boxes (model + δ 68%/95%, model alone 95% outline) against the data.");
        Ok(Some((caption, prediction_boxes(run, observable, &format!("kernel {kernel}: {observable}"))?)))
    }
}
