//! A calibration's figures: the corner plot of the posterior with the prior
//! shaded, prediction bands with the data, and δ(x) with its band.

use super::*;

pub(super) fn quantile(v: &[f64], q: f64) -> f64 {
    crate::engine::calibrate::sampler::diagnostics::quantile(v, q)
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

/// A corner plot's diagonal panel: each run's normalized histogram of
/// `param` with its median and 68% band, the prior's density and the truth.
pub(super) fn corner_marginal(
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
    let kind = run.curve_kind(observable);
    let x = run.pred_col(observable, kind, "x");
    let cols =
        |p: &str| ["q025", "q16", "median", "q84", "q975"].map(|q| run.pred_col(observable, kind, &format!("{p}_{q}")));
    let (model, md) = (cols("model"), cols("model_md"));
    let truth = run.pred_col(observable, kind, "truth");
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
                .y_label_area_size(76)
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
    let kind = run.curve_kind(observable);
    let x = run.pred_col(observable, kind, "x");
    let q = ["q025", "median", "q975"].map(|c| run.pred_col(observable, kind, &format!("delta_{c}")));
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
                .y_label_area_size(76)
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
