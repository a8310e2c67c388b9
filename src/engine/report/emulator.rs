//! Emulator validation figures from `validation_parity.parquet`: parity plots
//! per observable and z-score histograms against the standard normal.

use super::{range_of, svg, H, W};
use anyhow::{Context, Result};
use plotters::prelude::*;
use std::path::Path;

/// One held-out or cross-validated prediction.
pub struct ParityRow {
    pub set: String,
    pub observable: String,
    pub x: f64,
    pub simulated: f64,
    pub emulated: f64,
    pub sd: f64,
}

pub fn load_parity(path: &Path) -> Result<Vec<ParityRow>> {
    let df = crate::base::artifacts::read_parquet(path)?;
    let s = |c: &str| -> Result<Vec<String>> {
        Ok(df
            .column(c)
            .with_context(|| format!("{}: missing column '{c}'", path.display()))?
            .str()?
            .iter()
            .map(|v| v.unwrap_or("").to_string())
            .collect())
    };
    let f = |c: &str| -> Result<Vec<f64>> {
        Ok(df
            .column(c)
            .with_context(|| format!("{}: missing column '{c}'", path.display()))?
            .f64()?
            .iter()
            .map(|v| v.unwrap_or(f64::NAN))
            .collect())
    };
    let (set, obs, x, sim, emu, sd) = (s("set")?, s("observable")?, f("x")?, f("simulated")?, f("emulated")?, f("sd")?);
    Ok((0..df.height())
        .map(|i| ParityRow {
            set: set[i].clone(),
            observable: obs[i].clone(),
            x: x[i],
            simulated: sim[i],
            emulated: emu[i],
            sd: sd[i],
        })
        .collect())
}

/// Emulated against simulated values of one observable (±1σ emulator bars),
/// with the diagonal.
pub fn parity_plot(rows: &[&ParityRow], observable: &str) -> Result<String> {
    let r = range_of(rows.iter().flat_map(|p| [p.simulated, p.emulated - p.sd, p.emulated + p.sd]));
    svg(
        |root| {
            let mut chart = p!(ChartBuilder::on(root)
                .caption(format!("emulator parity: {observable}"), ("sans-serif", 16))
                .margin(8)
                .x_label_area_size(40)
                .y_label_area_size(64)
                .build_cartesian_2d(r.0..r.1, r.0..r.1));
            // Heavy-ion spectra are invariant yields; flows and ball-drop outputs carry their own units.
            let units = if observable.ends_with("spectrum") { " [GeV⁻²]" } else { "" };
            let (xd, yd) = (format!("simulated {observable}{units}"), format!("emulated {observable}{units}"));
            p!(chart.configure_mesh().x_desc(xd.as_str()).y_desc(yd.as_str()).draw());
            p!(chart
                .draw_series(DashedLineSeries::new(vec![(r.0, r.0), (r.1, r.1)], 6, 4, BLACK.stroke_width(1)))
                .map(|s| s
                    .label("emulated = simulated")
                    .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 14, y)], BLACK))));
            let blue = RGBColor(40, 90, 205);
            p!(chart
                .draw_series(rows.iter().map(|p| ErrorBar::new_vertical(
                    p.simulated,
                    p.emulated - p.sd,
                    p.emulated,
                    p.emulated + p.sd,
                    blue.mix(0.6).filled(),
                    3
                )))
                .map(|s| s.label("emulator mean ± 1σ").legend(move |(x, y)| Circle::new(
                    (x + 7, y),
                    3,
                    blue.filled()
                ))));
            super::draw_legend(&mut chart, SeriesLabelPosition::UpperLeft)?;
            Ok(())
        },
        W,
        H,
    )
}

/// Histogram of z = (emulated − simulated)/σ over all outputs, with N(0, 1).
pub fn z_histogram(rows: &[&ParityRow], label: &str) -> Result<String> {
    let z: Vec<f64> = rows.iter().map(|p| (p.emulated - p.simulated) / p.sd).filter(|v| v.is_finite()).collect();
    let (lo, hi, bins) = (-5.0, 5.0, 40);
    let width = (hi - lo) / bins as f64;
    let mut h = vec![0.0; bins];
    let mut outside = 0;
    for v in &z {
        if *v < lo || *v >= hi {
            outside += 1;
            continue;
        }
        h[((v - lo) / width) as usize] += 1.0 / (z.len() as f64 * width);
    }
    let top = h.iter().copied().fold(0.4, f64::max) * 1.1;
    svg(
        |root| {
            let mut chart = p!(ChartBuilder::on(root)
                .caption(
                    format!("emulator z-scores ({label}, {} outputs, {outside} beyond ±5)", z.len()),
                    ("sans-serif", 15)
                )
                .margin(8)
                .x_label_area_size(40)
                .y_label_area_size(56)
                .build_cartesian_2d(lo..hi, 0.0..top));
            p!(chart.configure_mesh().x_desc("z = (emulated − simulated) / σ_emulator").y_desc("density").draw());
            let blue = RGBColor(40, 90, 205);
            p!(chart
                .draw_series(h.iter().enumerate().map(|(k, v)| Rectangle::new(
                    [(lo + k as f64 * width, 0.0), (lo + (k + 1) as f64 * width, *v)],
                    blue.mix(0.45).filled()
                )))
                .map(|s| s
                    .label("validation outputs")
                    .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 14, y + 5)], blue.mix(0.45).filled()))));
            let normal: Vec<(f64, f64)> = (0..=200)
                .map(|k| lo + (hi - lo) * k as f64 / 200.0)
                .map(|v| (v, (-0.5 * v * v).exp() / (2.0 * std::f64::consts::PI).sqrt()))
                .collect();
            p!(chart.draw_series(LineSeries::new(normal, BLACK.stroke_width(2))).map(|s| s
                .label("N(0, 1): a calibrated emulator")
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 14, y)], BLACK))));
            super::draw_legend(&mut chart, SeriesLabelPosition::UpperRight)?;
            Ok(())
        },
        W,
        H,
    )
}
