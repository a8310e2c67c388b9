//! Locate: where the data leave the model, from the MD fit's δ(x) and the
//! no-MD fit's residuals.

use super::{ObservableMismatch, Region};
use crate::engine::calibrate::results::summary::PredictionRow;
use crate::engine::calibrate::{Calibration, Problem};

pub(super) fn locate(
    md_problem: &Problem,
    md: &Calibration,
    base_problem: &Problem,
    base: &Calibration,
) -> Vec<ObservableMismatch> {
    let theta_median: Vec<f64> =
        base_problem.simulator.parameter_names().iter().map(|n| base.summary.parameters[n].median).collect();
    let mut out = Vec::new();
    for b in &md_problem.likelihood.blocks {
        let (x_lo, x_hi) = (b.x[0], b.x[b.len() - 1]);
        let in_range = |kind: &str| -> Vec<&PredictionRow> {
            md.predictions
                .iter()
                .filter(|r| r.observable == b.name && r.kind == kind && r.x >= x_lo - 1e-12 && r.x <= x_hi + 1e-12)
                .collect()
        };
        // An emulated model predicts only at its training outputs (no grid
        // rows): its regions come from δ at the data points.
        let mut grid = in_range("grid");
        if grid.is_empty() {
            grid = in_range("data");
        }
        let mut regions: Vec<Region> = Vec::new();
        let mut open: Option<(f64, f64, &str)> = None;
        for r in &grid {
            let sign = if r.delta[0] > 0.0 {
                Some("above")
            } else if r.delta[4] < 0.0 {
                Some("below")
            } else {
                None
            };
            open = match (open, sign) {
                (Some((from, _, s)), Some(s2)) if s == s2 => Some((from, r.x, s)),
                (Some((from, to, s)), other) => {
                    regions.push(Region { x_from: from, x_to: to, sign: s.to_string() });
                    other.map(|s2| (r.x, r.x, s2))
                }
                (None, other) => other.map(|s2| (r.x, r.x, s2)),
            };
        }
        if let Some((from, to, s)) = open {
            regions.push(Region { x_from: from, x_to: to, sign: s.to_string() });
        }
        let map: Vec<(f64, f64)> =
            b.x.iter()
                .enumerate()
                .map(|(i, &x)| {
                    let d = md
                        .predictions
                        .iter()
                        .find(|r| r.observable == b.name && r.kind == "data" && r.x == x)
                        .map(|r| r.delta_mean)
                        .unwrap_or(0.0);
                    (x, d / b.error[i])
                })
                .collect();
        let (x_at_max, max_sigma) =
            map.iter().fold((x_lo, 0.0f64), |acc, &(x, z)| if z.abs() > acc.1 { (x, z.abs()) } else { acc });
        // δ's mean that could be computed nowhere is no evidence of a δ of zero.
        let max_sigma = if map.iter().all(|p| p.1.is_nan()) { f64::NAN } else { max_sigma };
        let sign = match regions.first() {
            None => "none".to_string(),
            Some(first) if regions.iter().all(|r| r.sign == first.sign) => first.sign.clone(),
            Some(_) => "mixed".to_string(),
        };
        let half = map.len() / 2;
        let mean_abs = |s: &[(f64, f64)]| s.iter().map(|p| p.1.abs()).sum::<f64>() / s.len().max(1) as f64;
        let grows_with_x = mean_abs(&map[half..]) > mean_abs(&map[..half]);
        let n = b.len();
        let mut eta = vec![0.0; n];
        base_problem.simulator.predict(b.model_index, &b.x, &theta_median, &mut eta);
        let mut model_cov = vec![0.0; n * n];
        base_problem.simulator.add_model_covariance(b.model_index, &b.x, &theta_median, 1.0, &mut model_cov);
        let residuals: Vec<(f64, f64)> = (0..n)
            .map(|i| {
                let band =
                    base.predictions.iter().find(|r| r.observable == b.name && r.kind == "data" && r.x == b.x[i]);
                // 95% band width / 3.92 = the posterior sd of η for a normal posterior.
                let (centre, sd_theta) =
                    band.map(|r| (r.model[2], (r.model[4] - r.model[0]) / 3.92)).unwrap_or((eta[i], 0.0));
                let var = b.error[i] * b.error[i] + sd_theta * sd_theta + model_cov[i * n + i];
                (b.x[i], (b.y[i] - centre) / var.sqrt())
            })
            .collect();
        let chi2: f64 = residuals.iter().map(|r| r.1 * r.1).sum();
        let residual_regions = residual_regions(&residuals);
        out.push(ObservableMismatch {
            observable: b.name.clone(),
            regions,
            max_sigma,
            x_at_max,
            sign,
            grows_with_x,
            r: md.summary.parameters[&format!("{}.r", b.name)].clone(),
            no_md_residuals: residuals,
            residual_regions,
            no_md_chi2: chi2,
            no_md_dof: b.len(),
            map,
        });
    }
    out
}

/// Where the data leave the model, in words: the MD trend of the worst
/// observable when its δ band is clear of zero with one sign, otherwise the
/// no-MD residual regions of up to three observables.
pub(super) fn mismatch_phrase(mismatch: &[ObservableMismatch]) -> String {
    let Some(worst) = mismatch.iter().max_by(|a, b| a.max_sigma.total_cmp(&b.max_sigma)) else {
        return String::new();
    };
    if worst.sign == "below" || worst.sign == "above" {
        let below = worst.sign == "below";
        return format!(
            "{} {}{} {} the model{}; ",
            worst.observable,
            if below { "falls" } else { "rises" },
            if worst.grows_with_x { " increasingly" } else { "" },
            if below { "below" } else { "above" },
            if worst.grows_with_x { " as x grows" } else { "" }
        );
    }
    let peak = |m: &ObservableMismatch| m.no_md_residuals.iter().map(|r| r.1.abs()).fold(0.0, f64::max);
    let mut located: Vec<&ObservableMismatch> = mismatch.iter().filter(|m| !m.residual_regions.is_empty()).collect();
    located.sort_by(|a, b| peak(b).total_cmp(&peak(a)));
    if located.is_empty() {
        return format!("{} deviates from the model by up to {:.1}σ of its error; ", worst.observable, worst.max_sigma);
    }
    let parts: Vec<String> = located
        .iter()
        .take(3)
        .map(|m| {
            let ranges: Vec<String> = m
                .residual_regions
                .iter()
                .map(|r| format!("{} the model for x in [{:.2}, {:.2}]", r.sign, r.x_from, r.x_to))
                .collect();
            format!("{} lies {} (up to {:.1}σ)", m.observable, ranges.join(" and "), peak(m))
        })
        .collect();
    format!("fitted alone, the model misses: {}; ", parts.join("; "))
}

/// Maximal runs of same-sign standardized residuals beyond 2, kept when they
/// hold two or more points or one beyond 3 (a lone 2σ point among dozens is
/// expected by chance).
fn residual_regions(z: &[(f64, f64)]) -> Vec<Region> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < z.len() {
        let sign = if z[i].1 > 2.0 {
            1.0
        } else if z[i].1 < -2.0 {
            -1.0
        } else {
            0.0
        };
        if sign == 0.0 {
            i += 1;
            continue;
        }
        let start = i;
        while i < z.len() && z[i].1 * sign > 2.0 {
            i += 1;
        }
        let run = &z[start..i];
        if run.len() >= 2 || run.iter().any(|p| p.1.abs() > 3.0) {
            out.push(Region {
                x_from: run[0].0,
                x_to: run[run.len() - 1].0,
                sign: if sign > 0.0 { "above" } else { "below" }.into(),
            });
        }
    }
    out
}
