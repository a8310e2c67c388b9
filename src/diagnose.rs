//! `mdpipe diagnose`: locate a model-data mismatch, name the physics that was
//! left out, model it, and show the fit improve.
//!
//! 1. Locate: calibrate with and without MD; read δ(x) off the MD posterior.
//! 2. Explain: calibrate the model augmented by each candidate correction from
//!    the model's library and rank them by SMC log-evidence against the base.
//! 3. Repair: refit with the winner, with and without MD, and compare.
//!
//! Decision rule (log Bayes factors, Kass & Raftery's "strong" = 3):
//! * a candidate is named when it beats the base model by more than
//!   `strong_log_bf`, fits adequately (χ² p-value ≥ `min_p_value` at its
//!   posterior median) and is not itself beaten by the MD fit by more than
//!   `strong_log_bf`;
//! * otherwise the verdict is "unexplained" when the mismatch is significant
//!   (MD beats the base by more than `strong_log_bf`, or the base χ² has
//!   p < `min_p_value`), and "none" when it is not.

use crate::artifacts::{self, Provenance};
use crate::calibrate::summary::{ParamSummary, PredictionRow, Summary};
use crate::calibrate::{self, Calibration, Overrides, Problem};
use crate::config::{CandidateConfig, Config, ModelConfig, ParamSpec};
use crate::gp::DiscrepancyKernel;
use crate::models::{ball_drop, AugmentedBallDrop, EmulatedModel, Simulator};
use anyhow::{anyhow, bail, Context, Result};
use statrs::distribution::{ChiSquared, ContinuousCDF};
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;

#[derive(Clone, Debug)]
pub struct DiagnoseSettings {
    pub kernel: DiscrepancyKernel,
    pub strong_log_bf: f64,
    pub min_p_value: f64,
    pub show_progress: bool,
    /// Refit the winner with MD on top (step 3); blind tests skip it.
    pub repair: bool,
}

impl Default for DiagnoseSettings {
    fn default() -> Self {
        DiagnoseSettings { kernel: DiscrepancyKernel::KernelII, strong_log_bf: 3.0, min_p_value: 1e-3, show_progress: false, repair: true }
    }
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Region {
    pub x_from: f64,
    pub x_to: f64,
    /// "above": data above the model (δ > 0); "below": δ < 0.
    pub sign: String,
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct ObservableMismatch {
    pub observable: String,
    /// x ranges (within the data) where the 95% band of δ excludes zero.
    pub regions: Vec<Region>,
    /// Largest |posterior-mean δ| at a data point, in units of its 1σ error.
    pub max_sigma: f64,
    pub x_at_max: f64,
    /// "above", "below", "mixed" or "none".
    pub sign: String,
    /// Whether |δ| grows with x over the data.
    pub grows_with_x: bool,
    /// Posterior of the growth exponent r of the discrepancy kernel.
    pub r: ParamSummary,
    /// Posterior-predictive check of the no-MD fit: residuals (y − η̂)
    /// standardized by the whole predictive sd (measurement error, posterior
    /// spread of η and, for an emulator, its own uncertainty), and χ².
    pub no_md_residuals: Vec<(f64, f64)>,
    /// Runs of consecutive data points whose no-MD residual exceeds 2 in
    /// size with one sign (kept if two or more points, or one beyond 3): where
    /// the model alone misses. Where an emulator's uncertainty leaves the δ
    /// band wide (`regions` empty), this still locates the mismatch.
    #[serde(default)]
    pub residual_regions: Vec<Region>,
    pub no_md_chi2: f64,
    pub no_md_dof: usize,
    /// Posterior-mean δ/σ at each data point: one row of the mismatch map.
    pub map: Vec<(f64, f64)>,
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct CandidateResult {
    pub name: String,
    pub description: String,
    pub log_evidence: f64,
    pub log_evidence_err: f64,
    /// Against the base model without MD.
    pub log_bayes_factor: f64,
    pub log_bayes_factor_err: f64,
    pub parameters: BTreeMap<String, ParamSummary>,
    pub chi2_per_dof: f64,
    pub p_value: f64,
    pub converged: bool,
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Verdict {
    /// A candidate name, "none" or "unexplained".
    pub best: String,
    pub statement: String,
    /// Posterior probability of the verdict's model among the base, MD and
    /// candidate models, with equal prior odds.
    pub confidence: f64,
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct FitFigures {
    pub label: String,
    pub chi2_per_dof: f64,
    pub log_evidence: f64,
    pub log_evidence_err: f64,
    pub parameters: BTreeMap<String, ParamSummary>,
    /// Largest |posterior-mean δ|/σ per observable (0 without MD).
    pub delta_max_sigma: BTreeMap<String, f64>,
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Improvement {
    pub before: Vec<FitFigures>,
    pub after: Vec<FitFigures>,
    /// Width of the 95% interval of each model parameter, before (MD) / after (repaired).
    pub interval_narrowing: BTreeMap<String, f64>,
    /// The largest narrowing these data allow: the MD width over the repaired
    /// model's Cramér–Rao 95% width (2 × 1.96 × sd) at its posterior median.
    /// Empty for emulated models and for parameters the data cannot identify.
    #[serde(default)]
    pub information_limit: BTreeMap<String, f64>,
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Diagnosis {
    pub mismatch: Vec<ObservableMismatch>,
    pub candidates: Vec<CandidateResult>,
    pub verdict: Verdict,
    pub improvement: Option<Improvement>,
    pub base_log_evidence: f64,
    pub md_log_evidence: f64,
    pub provenance: Provenance,
}

/// Everything `diagnose` computed, for the report.
pub struct DiagnoseRun {
    pub diagnosis: Diagnosis,
    pub base: Calibration,
    pub md: Calibration,
    pub candidates: Vec<(String, Calibration)>,
    pub repaired_md: Option<Calibration>,
}

/// One candidate correction as diagnose sees it: a model that adds named
/// physics (and possibly parameters) to the base model.
pub struct CandidateModel {
    pub name: String,
    pub description: String,
    /// Parameters the candidate adds to θ, with their uniform priors.
    pub extra_parameters: Vec<(String, ParamSpec)>,
    pub simulator: Arc<dyn Simulator>,
}

impl CandidateModel {
    /// The config with the candidate's parameters added to θ.
    fn config(&self, base: &Config) -> Config {
        let mut cfg = base.clone();
        for (name, spec) in &self.extra_parameters {
            cfg.parameters.insert(name.clone(), spec.clone());
        }
        cfg
    }
}

/// The candidate corrections a model offers: the ball drop's built-in
/// library, or for an emulated model the variants declared in `[[candidates]]`.
pub fn candidate_models(config: &Config) -> Result<Vec<CandidateModel>> {
    match &config.model {
        ModelConfig::BallDrop { h0 } => Ok(ball_drop::CANDIDATES
            .iter()
            .map(|c| CandidateModel {
                name: c.name.to_string(),
                description: c.description.to_string(),
                extra_parameters: vec![(c.parameter.to_string(), ParamSpec { min: c.bounds.0, max: c.bounds.1, truth: None, units: c.units.to_string() })],
                simulator: Arc::new(AugmentedBallDrop { h0: *h0, candidate: *c }),
            })
            .collect()),
        ModelConfig::Emulator { .. } => config.candidates.iter().map(|c| declared_candidate(config, c)).collect(),
    }
}

/// A user-declared model variant: an emulator trained on runs with the extra
/// physics switched on. Its parameters must be the base θ plus the variant's
/// own, whose priors the declaration gives.
fn declared_candidate(config: &Config, c: &CandidateConfig) -> Result<CandidateModel> {
    let file = config.path.display();
    let dir = config.resolve(&c.emulator);
    let model = EmulatedModel::load(&dir).with_context(|| format!("{file}: [[candidates]] {}: loading the variant emulator {}", c.name, dir.display()))?;
    let names = model.parameter_names();
    if let Some(missing) = config.parameters.keys().find(|p| !names.contains(p)) {
        bail!("{file}: [[candidates]] {}: the variant emulator {} lacks the model parameter '{missing}' (it has {})", c.name, dir.display(), names.join(", "));
    }
    let mut extra = Vec::new();
    for n in names.iter().filter(|n| !config.parameters.contains_key(*n)) {
        let spec = c.parameters.get(n).ok_or_else(|| anyhow!("{file}: [[candidates]] {}: give prior bounds for the variant's own parameter '{n}' in [candidates.parameters.{n}]", c.name))?;
        if !(spec.min.is_finite() && spec.max.is_finite() && spec.min < spec.max) {
            bail!("{file}: [[candidates]] {}: [candidates.parameters.{n}]: bounds must satisfy min < max, got min = {}, max = {}", c.name, spec.min, spec.max);
        }
        extra.push((n.clone(), spec.clone()));
    }
    if let Some(unused) = c.parameters.keys().find(|k| !names.contains(k)) {
        bail!("{file}: [[candidates]] {}: parameter '{unused}' is not one of the variant emulator's ({})", c.name, names.join(", "));
    }
    Ok(CandidateModel { name: c.name.clone(), description: c.description.clone(), extra_parameters: extra, simulator: Arc::new(model) })
}

fn p_value(chi2: f64, dof: usize) -> f64 {
    ChiSquared::new(dof.max(1) as f64).map(|d| 1.0 - d.cdf(chi2)).unwrap_or(f64::NAN)
}

fn evidence(s: &Summary) -> (f64, f64) {
    (s.log_evidence.unwrap_or(f64::NEG_INFINITY), s.log_evidence_err.unwrap_or(f64::NAN))
}

fn delta_max_sigma(problem: &Problem, preds: &[PredictionRow]) -> BTreeMap<String, f64> {
    let mut out = BTreeMap::new();
    for b in &problem.likelihood.blocks {
        let m = preds
            .iter()
            .filter(|r| r.observable == b.name && r.kind == "data")
            .filter_map(|r| b.x.iter().position(|x| *x == r.x).map(|i| (r.delta_mean / b.error[i]).abs()))
            .fold(0.0, f64::max);
        out.insert(b.name.clone(), m);
    }
    out
}

fn figures(label: &str, problem: &Problem, cal: &Calibration) -> FitFigures {
    let (z, e) = evidence(&cal.summary);
    let theta: Vec<String> = problem.simulator.parameter_names();
    FitFigures {
        label: label.to_string(),
        chi2_per_dof: cal.summary.fit.chi2_per_dof,
        log_evidence: z,
        log_evidence_err: e,
        parameters: theta.iter().map(|n| (n.clone(), cal.summary.parameters[n].clone())).collect(),
        delta_max_sigma: delta_max_sigma(problem, &cal.predictions),
    }
}

fn locate(md_problem: &Problem, md: &Calibration, base_problem: &Problem, base: &Calibration) -> Vec<ObservableMismatch> {
    let theta_median: Vec<f64> = base_problem.simulator.parameter_names().iter().map(|n| base.summary.parameters[n].median).collect();
    let mut out = Vec::new();
    for b in &md_problem.likelihood.blocks {
        let (x_lo, x_hi) = (b.x[0], b.x[b.len() - 1]);
        let grid: Vec<&PredictionRow> = md.predictions.iter().filter(|r| r.observable == b.name && r.kind == "grid" && r.x >= x_lo - 1e-12 && r.x <= x_hi + 1e-12).collect();
        let mut regions: Vec<Region> = Vec::new();
        let mut open: Option<(f64, f64, &str)> = None;
        for r in &grid {
            let sign = if r.delta[0] > 0.0 { Some("above") } else if r.delta[4] < 0.0 { Some("below") } else { None };
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
        let map: Vec<(f64, f64)> = b
            .x
            .iter()
            .enumerate()
            .map(|(i, &x)| {
                let d = md.predictions.iter().find(|r| r.observable == b.name && r.kind == "data" && r.x == x).map(|r| r.delta_mean).unwrap_or(0.0);
                (x, d / b.error[i])
            })
            .collect();
        let (x_at_max, max_sigma) = map.iter().fold((x_lo, 0.0f64), |acc, &(x, z)| if z.abs() > acc.1 { (x, z.abs()) } else { acc });
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
                let band = base.predictions.iter().find(|r| r.observable == b.name && r.kind == "data" && r.x == b.x[i]);
                // 95% band width / 3.92 = the posterior sd of η for a normal posterior.
                let (centre, sd_theta) = band.map(|r| (r.model[2], (r.model[4] - r.model[0]) / 3.92)).unwrap_or((eta[i], 0.0));
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
fn mismatch_phrase(mismatch: &[ObservableMismatch]) -> String {
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
            let ranges: Vec<String> = m.residual_regions.iter().map(|r| format!("{} the model for x in [{:.2}, {:.2}]", r.sign, r.x_from, r.x_to)).collect();
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
        let sign = if z[i].1 > 2.0 { 1.0 } else if z[i].1 < -2.0 { -1.0 } else { 0.0 };
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
            out.push(Region { x_from: run[0].0, x_to: run[run.len() - 1].0, sign: if sign > 0.0 { "above" } else { "below" }.into() });
        }
    }
    out
}

/// Runs the whole diagnosis. `out`, when given, receives every calibration.
pub fn run(config: &Config, overrides: &Overrides, seed: u64, settings: &DiagnoseSettings, out: Option<&Path>) -> Result<DiagnoseRun> {
    let write = |name: &str, p: &Problem, c: &Calibration| -> Result<()> {
        if let Some(dir) = out {
            calibrate::write_outputs(&dir.join(name), p, c)?;
        }
        Ok(())
    };
    let base_problem = Problem::new(config, &Overrides { kernel: Some(None), ..overrides.clone() })?;
    let base = calibrate::run(&base_problem, seed, settings.show_progress)?;
    write("base_no_md", &base_problem, &base)?;
    let md_problem = Problem::new(config, &Overrides { kernel: Some(Some(settings.kernel)), ..overrides.clone() })?;
    let md = calibrate::run(&md_problem, seed.wrapping_add(1), settings.show_progress)?;
    write("base_md", &md_problem, &md)?;
    let (z_base, e_base) = evidence(&base.summary);
    let (z_md, e_md) = evidence(&md.summary);
    let mismatch = locate(&md_problem, &md, &base_problem, &base);

    let mut candidates = Vec::new();
    let mut candidate_runs = Vec::new();
    for (k, cand) in candidate_models(config)?.into_iter().enumerate() {
        let problem = Problem::with_simulator(&cand.config(config), &Overrides { kernel: Some(None), ..overrides.clone() }, cand.simulator.clone())?;
        let cal = calibrate::run(&problem, seed.wrapping_add(10 + k as u64), settings.show_progress)?;
        write(&format!("candidate_{}", cand.name), &problem, &cal)?;
        let (z, e) = evidence(&cal.summary);
        candidates.push(CandidateResult {
            name: cand.name.clone(),
            description: cand.description.clone(),
            log_evidence: z,
            log_evidence_err: e,
            log_bayes_factor: z - z_base,
            log_bayes_factor_err: (e * e + e_base * e_base).sqrt(),
            parameters: problem.simulator.parameter_names().iter().map(|n| (n.clone(), cal.summary.parameters[n].clone())).collect(),
            chi2_per_dof: cal.summary.fit.chi2_per_dof,
            p_value: p_value(cal.summary.fit.chi2, cal.summary.fit.dof),
            converged: cal.summary.diagnostics.converged,
        });
        candidate_runs.push((cand, problem, cal));
    }
    let mut order: Vec<usize> = (0..candidates.len()).collect();
    order.sort_by(|&a, &b| candidates[b].log_evidence.total_cmp(&candidates[a].log_evidence));
    let candidates: Vec<CandidateResult> = order.iter().map(|&i| candidates[i].clone()).collect();
    let mut candidate_runs: Vec<_> = candidate_runs.into_iter().map(Some).collect();
    let candidate_runs: Vec<_> = order.iter().map(|&i| candidate_runs[i].take().unwrap()).collect();

    let base_p = p_value(base.summary.fit.chi2, base.summary.fit.dof);
    let significant = z_md - z_base > settings.strong_log_bf || base_p < settings.min_p_value;
    let best = candidates.first();
    let named = best.filter(|c| {
        c.log_bayes_factor > settings.strong_log_bf && c.p_value >= settings.min_p_value && c.log_evidence > z_md - settings.strong_log_bf
    });
    // Posterior model probabilities with equal prior odds.
    let mut all_z = vec![z_base, z_md];
    all_z.extend(candidates.iter().map(|c| c.log_evidence));
    let lse = crate::calibrate::smc::log_sum_exp(&all_z);
    let prob = |z: f64| (z - lse).exp();

    let worst = mismatch.iter().max_by(|a, b| a.max_sigma.total_cmp(&b.max_sigma));
    let verdict = match named {
        Some(c) => {
            let (cand, _, _) = &candidate_runs[0];
            let fitted: Vec<String> = cand
                .extra_parameters
                .iter()
                .map(|(n, spec)| {
                    let p = &c.parameters[n];
                    format!("{n} = {:.3} [{:.3}, {:.3}]{}", p.median, p.q025, p.q975, if spec.units.is_empty() { String::new() } else { format!(" {}", spec.units) })
                })
                .collect();
            let fitted = if fitted.is_empty() { "with no free parameter of its own".to_string() } else { fitted.join(", ") };
            let trend = mismatch_phrase(&mismatch);
            let runner = candidates.get(1).map(|r| format!(" over {} by log BF = {:.1}", r.name, c.log_evidence - r.log_evidence)).unwrap_or_default();
            Verdict {
                best: c.name.clone(),
                statement: format!(
                    "{trend}the data favour {} ({}), {fitted}{runner}; against the model as it is, log BF = {:.1}.",
                    c.name.replace('_', " "),
                    c.description,
                    c.log_bayes_factor
                ),
                confidence: prob(c.log_evidence),
            }
        }
        None if significant => {
            let w = worst.map(|w| format!("{} deviates by up to {:.1}σ (at x = {:.3}); ", w.observable, w.max_sigma, w.x_at_max)).unwrap_or_default();
            let b = best.map(|c| format!("the best candidate, {}, reaches χ²/dof = {:.2} (p = {:.1e}) and log BF = {:.1} against the model; ", c.name, c.chi2_per_dof, c.p_value, c.log_bayes_factor)).unwrap_or_default();
            Verdict {
                best: "unexplained".into(),
                statement: format!("a mismatch that no candidate explains: {w}{b}the model-discrepancy fit (log BF = {:.1} against no MD) stays the honest answer.", z_md - z_base),
                confidence: prob(z_md),
            }
        }
        None => Verdict {
            best: "none".into(),
            statement: format!(
                "no significant mismatch: δ is consistent with zero (largest posterior-mean |δ| = {:.1}σ), the model alone fits with χ²/dof = {:.2}, and no candidate is favoured (best log BF = {:.1}).",
                worst.map(|w| w.max_sigma).unwrap_or(0.0),
                base.summary.fit.chi2_per_dof,
                best.map(|c| c.log_bayes_factor).unwrap_or(f64::NAN)
            ),
            confidence: prob(z_base),
        },
    };

    // Repair: refit the winner with MD on top, to show δ shrink.
    let mut improvement = None;
    let mut repaired_md = None;
    if named.is_some() && settings.repair {
        let (cand, rep_problem, rep) = &candidate_runs[0];
        let rep_md_problem = Problem::with_simulator(&cand.config(config), &Overrides { kernel: Some(Some(settings.kernel)), ..overrides.clone() }, cand.simulator.clone())?;
        let rep_md = calibrate::run(&rep_md_problem, seed.wrapping_add(99), settings.show_progress)?;
        write("repaired_md", &rep_md_problem, &rep_md)?;
        let before = vec![figures("model, no MD", &base_problem, &base), figures("model + MD", &md_problem, &md)];
        let after = vec![figures(&format!("model + {}", cand.name), rep_problem, rep), figures(&format!("model + {} + MD", cand.name), &rep_md_problem, &rep_md)];
        let interval_narrowing = base_problem
            .simulator
            .parameter_names()
            .iter()
            .map(|n| (n.clone(), md.summary.parameters[n].width95() / rep.summary.parameters[n].width95()))
            .collect();
        let information_limit = information_limit(rep_problem, rep, &md);
        improvement = Some(Improvement { before, after, interval_narrowing, information_limit });
        repaired_md = Some(rep_md);
    }
    let _ = e_md;
    let diagnosis = Diagnosis {
        mismatch,
        candidates,
        verdict,
        improvement,
        base_log_evidence: z_base,
        md_log_evidence: z_md,
        provenance: base_problem.provenance(seed, "diagnose"),
    };
    let candidates = candidate_runs.into_iter().map(|(c, _, cal)| (c.name, cal)).collect();
    if let Some(dir) = out {
        artifacts::write_json_atomic(&dir.join("diagnosis.json"), &diagnosis)?;
    }
    Ok(DiagnoseRun { diagnosis, base, md, candidates, repaired_md })
}

/// MD 95% width over the repaired model's Cramér–Rao 95% width, per
/// parameter of the base model, at the repaired posterior median.
fn information_limit(rep_problem: &Problem, rep: &Calibration, md: &Calibration) -> BTreeMap<String, f64> {
    let lik = &rep_problem.likelihood;
    let names = rep_problem.simulator.parameter_names();
    let theta: Vec<f64> = names.iter().map(|n| rep.summary.parameters[n].median).collect();
    // Central differences at 1e-5 of the prior range: truncation ~1e-10 relative.
    let steps: Vec<f64> = (0..lik.n_theta).map(|k| 1e-5 * (rep_problem.prior.upper[k] - rep_problem.prior.lower[k])).collect();
    let Some(sd) = lik.cramer_rao_sd(&theta, &steps) else {
        return BTreeMap::new();
    };
    names
        .iter()
        .zip(&sd)
        .filter_map(|(n, s)| md.summary.parameters.get(n).map(|p| (n.clone(), p.width95() / (2.0 * 1.959964 * s))))
        .collect()
}

/// Plain-text summary for the terminal.
pub fn print(d: &Diagnosis) {
    println!("Locate (model + MD; δ in units of the measurement error):");
    for m in &d.mismatch {
        let show = |rs: &[Region]| -> String {
            if rs.is_empty() {
                "no region".into()
            } else {
                rs.iter().map(|r| format!("[{:.2}, {:.2}] {}", r.x_from, r.x_to, r.sign)).collect::<Vec<_>>().join(", ")
            }
        };
        println!(
            "  {:<14} max |δ| = {:>5.1}σ at x = {:.2}; δ ≠ 0 in {}; r = {:.2} [{:.2}, {:.2}]; no-MD χ²/n = {:.1}, misses in {}",
            m.observable,
            m.max_sigma,
            m.x_at_max,
            show(&m.regions),
            m.r.median,
            m.r.q025,
            m.r.q975,
            m.no_md_chi2 / m.no_md_dof as f64,
            show(&m.residual_regions)
        );
    }
    println!("Explain (log Bayes factor against the model without MD; log BF of the MD fit: {:.1}):", d.md_log_evidence - d.base_log_evidence);
    for c in &d.candidates {
        println!("  {:<16} log BF = {:>8.1} ± {:.1}   χ²/dof = {:>6.2}", c.name, c.log_bayes_factor, c.log_bayes_factor_err, c.chi2_per_dof);
    }
    println!("Verdict: {} (confidence {:.2})", d.verdict.best, d.verdict.confidence);
    println!("  {}", d.verdict.statement);
    if let Some(imp) = &d.improvement {
        println!("Repair (before → after):");
        for f in imp.before.iter().chain(&imp.after) {
            let g: Vec<String> = f.parameters.iter().map(|(n, p)| format!("{n} = {:.3} [{:.3}, {:.3}]", p.median, p.q025, p.q975)).collect();
            let dmax = f.delta_max_sigma.values().cloned().fold(0.0, f64::max);
            println!("  {:<34} χ²/dof {:>6.2}  log Z {:>8.2}  max|δ| {:>4.1}σ  {}", f.label, f.chi2_per_dof, f.log_evidence, dmax, g.join(", "));
        }
        for (n, r) in &imp.interval_narrowing {
            let limit = imp.information_limit.get(n).map(|l| format!(" (the data's Cramér–Rao limit: {l:.1}x)")).unwrap_or_default();
            println!("  95% interval of {n}: {r:.1}x narrower than with MD alone{limit}");
        }
    }
}
