//! Posterior summaries (`summary.json`) and posterior-predictive bands
//! (`predictions.parquet`).

use super::diagnostics::{self, ParamDiagnostics};
use super::smc::{SmcOutput, SmcStep};
use super::{Chains, Problem};
use crate::base::artifacts::Provenance;
use crate::engine::gp::{discrepancy_cross_cov, pow_r, CholeskyWorkspace, DiscrepancyKernel};
use crate::engine::model::Units;
use anyhow::Result;
use polars::prelude::*;
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use rand_xoshiro::Xoshiro256PlusPlus;
use rayon::prelude::*;
use std::collections::BTreeMap;

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize, PartialEq)]
pub struct ParamSummary {
    pub median: f64,
    pub q025: f64,
    pub q975: f64,
    pub q16: f64,
    pub q84: f64,
    pub mean: f64,
    pub sd: f64,
}

impl ParamSummary {
    pub fn from_draws(draws: &[f64]) -> Self {
        let mut v = draws.to_vec();
        v.sort_by(|a, b| a.total_cmp(b));
        let n = v.len() as f64;
        let mean = v.iter().sum::<f64>() / n;
        let sd = (v.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / (n - 1.0).max(1.0)).sqrt();
        let q = |p| diagnostics::quantile_sorted(&v, p);
        ParamSummary { median: q(0.5), q025: q(0.025), q975: q(0.975), q16: q(0.16), q84: q(0.84), mean, sd }
    }

    pub fn covers(&self, value: f64) -> bool {
        self.q025 <= value && value <= self.q975
    }

    pub fn width95(&self) -> f64 {
        self.q975 - self.q025
    }
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum SamplerDetails {
    Smc {
        replicates: usize,
        particles_per_replicate: usize,
        replicate_log_evidence: Vec<f64>,
        tempering_steps: Vec<usize>,
        /// Schedule of the first replicate.
        schedule: Vec<SmcStepRecord>,
        unique_fraction: Vec<f64>,
        /// Evaluations of one observable's term alone (its own φ moves, or,
        /// for a joint likelihood, their screens), all replicates;
        /// `likelihood_evaluations` counts whole-likelihood evaluations only.
        #[serde(default)]
        term_evaluations: u64,
    },
    Ensemble {
        walkers: usize,
        acceptance: f64,
    },
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct SmcStepRecord {
    pub beta: f64,
    pub mcmc_steps: usize,
    pub acceptance: f64,
    /// Joint move, then shared parameters, then each observable's own φ.
    #[serde(default)]
    pub group_acceptance: Vec<f64>,
}

impl From<&SmcStep> for SmcStepRecord {
    fn from(s: &SmcStep) -> Self {
        SmcStepRecord {
            beta: s.beta,
            mcmc_steps: s.mcmc_steps,
            acceptance: s.acceptance,
            group_acceptance: s.group_acceptance.clone(),
        }
    }
}

impl SamplerDetails {
    pub fn from_smc(out: &SmcOutput) -> Self {
        SamplerDetails::Smc {
            replicates: out.replicates.len(),
            particles_per_replicate: out.chains.chains.first().map(|c| c.len() / out.chains.dim).unwrap_or(0),
            replicate_log_evidence: out.replicates.iter().map(|r| r.log_evidence).collect(),
            tempering_steps: out.replicates.iter().map(|r| r.steps.len()).collect(),
            schedule: out
                .replicates
                .first()
                .map(|r| r.steps.iter().map(SmcStepRecord::from).collect())
                .unwrap_or_default(),
            unique_fraction: out.replicates.iter().map(|r| r.unique_fraction).collect(),
            term_evaluations: out.replicates.iter().map(|r| r.term_evaluations).sum(),
        }
    }
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Diagnostics {
    pub converged: bool,
    pub warnings: Vec<String>,
    pub parameters: Vec<ParamDiagnostics>,
    pub draws: usize,
    pub likelihood_evaluations: u64,
    pub wall_seconds: f64,
    pub likelihood_evaluations_per_second: f64,
    /// Smallest bulk/tail ESS over parameters, per second of wall time.
    pub min_ess_per_second: f64,
    /// Covariance matrices that needed jitter during this run.
    pub jitter_events: usize,
    /// θ at which the model could not be computed (an ODE that failed to
    /// integrate), each given zero likelihood.
    #[serde(default)]
    pub model_failures: u64,
    pub sampler: SamplerDetails,
}

impl Diagnostics {
    pub fn note_model_failures(&mut self, failures: u64) {
        self.model_failures = failures;
        if failures > 0 {
            self.warnings.push(format!(
                "the model could not be computed at {failures} parameter points (given zero likelihood)"
            ));
        }
    }
}

/// Goodness of fit of the model alone at the posterior median θ: the
/// generalized χ² `rᵀ C⁻¹ r` with the covariance of the no-MD likelihood,
/// `C = diag(σ²)` plus the data's covariance beyond the errors (`[data]
/// covariance`) and, for an emulator, its predictive covariance (without it
/// an emulated model would be judged as if it were exact).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct FitQuality {
    pub chi2: f64,
    pub dof: usize,
    pub chi2_per_dof: f64,
    /// χ² per observable.
    pub per_observable: BTreeMap<String, f64>,
    /// The model's own share of the predictive variance at the data points,
    /// in the observable where it is largest (`per_observable_share`): 0 for
    /// an exact model; for an emulator, how much of the fit rests on its
    /// uncertainty. The worst observable, not an average, because a
    /// mismatch is local: a variant emulator coarse in just the bins where
    /// the candidate differs from the model can fit them on its variance
    /// while every other observable dilutes an average.
    #[serde(default)]
    pub model_variance_share: f64,
    /// Per observable, `tr(M C⁻¹) / n` with M the model's covariance over its
    /// n points and C = M + the data's: the mean over the data's whitened
    /// directions of the model's fraction, which for independent points is
    /// the mean of m_i / (m_i + σ_i²). Unlike a ratio of summed variances it
    /// does not change with units, so a spectrum's low-pT bins in thousands
    /// cannot outvote its high-pT bins.
    #[serde(default)]
    pub per_observable_share: BTreeMap<String, f64>,
}

/// Past this share of the predictive variance the emulator, rather than the
/// data, decides much of a fit: `calibrate` warns and `diagnose` cautions.
pub const EMULATOR_DOMINATES: f64 = 0.5;

impl FitQuality {
    /// Whether the fit rests mostly on the model's (emulator's) own uncertainty.
    pub fn emulator_dominates(&self) -> bool {
        self.model_variance_share > EMULATOR_DOMINATES
    }
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Summary {
    pub name: String,
    pub kernel: String,
    pub observables: Vec<String>,
    pub sampler: String,
    pub parameters: BTreeMap<String, ParamSummary>,
    /// Parameter order as in `posterior.parquet`.
    pub parameter_order: Vec<String>,
    /// True values from the config, where known.
    pub truth: BTreeMap<String, f64>,
    /// Units of x, the observables and the parameters (from the model family).
    #[serde(default)]
    pub units: Units,
    /// Uniform prior bounds of every parameter.
    #[serde(default)]
    pub prior_bounds: BTreeMap<String, [f64; 2]>,
    pub log_evidence: Option<f64>,
    pub log_evidence_err: Option<f64>,
    pub fit: FitQuality,
    pub diagnostics: Diagnostics,
    pub provenance: Provenance,
}

#[allow(clippy::too_many_arguments)]
pub fn summarize(
    problem: &Problem,
    chains: &Chains,
    evidence: Option<(f64, f64)>,
    sampler: SamplerDetails,
    evaluations: u64,
    wall_seconds: f64,
    jitter_events: usize,
    seed: u64,
) -> Summary {
    let mut parameters = BTreeMap::new();
    let per_param: Vec<ParamDiagnostics> = (0..chains.dim)
        .into_par_iter()
        .map(|p| diagnostics::diagnose_param(&chains.names[p], &chains.param_chains(p)))
        .collect();
    for p in 0..chains.dim {
        parameters.insert(chains.names[p].clone(), ParamSummary::from_draws(&chains.param(p)));
    }
    let mut warnings = Vec::new();
    for d in &per_param {
        if d.rhat > diagnostics::RHAT_MAX {
            warnings.push(format!("{}: R-hat {:.3} > {}", d.name, d.rhat, diagnostics::RHAT_MAX));
        }
        let ess = d.ess_bulk.min(d.ess_tail);
        if ess < diagnostics::ESS_MIN || !ess.is_finite() {
            warnings.push(format!("{}: ESS {:.0} < {}", d.name, ess, diagnostics::ESS_MIN));
        }
    }
    if jitter_events > 0 {
        warnings.push(format!("{jitter_events} covariance matrices needed diagonal jitter to factorize"));
    }
    let min_ess = per_param.iter().map(|d| d.ess_bulk.min(d.ess_tail)).fold(f64::INFINITY, f64::min);
    let theta_median: Vec<f64> = problem.simulator.parameter_names().iter().map(|n| parameters[n].median).collect();
    Summary {
        name: problem.analysis.name.clone(),
        kernel: DiscrepancyKernel::label(problem.likelihood.kernel).to_string(),
        observables: problem.observables(),
        sampler: problem.sampler.label().to_string(),
        parameter_order: chains.names.clone(),
        parameters,
        truth: problem.analysis.truth_values(),
        units: problem.analysis.units.clone(),
        prior_bounds: (0..problem.prior.dim())
            .map(|i| (problem.prior.names[i].clone(), [problem.prior.lower[i], problem.prior.upper[i]]))
            .collect(),
        log_evidence: evidence.map(|e| e.0),
        log_evidence_err: evidence.map(|e| e.1),
        fit: fit_quality(problem, &theta_median),
        diagnostics: Diagnostics {
            converged: warnings.is_empty(),
            warnings,
            parameters: per_param,
            draws: chains.n_draws(),
            likelihood_evaluations: evaluations,
            wall_seconds,
            likelihood_evaluations_per_second: evaluations as f64 / wall_seconds.max(1e-9),
            min_ess_per_second: min_ess / wall_seconds.max(1e-9),
            jitter_events,
            model_failures: 0,
            sampler,
        },
        provenance: problem.provenance(seed, "calibrate"),
    }
}

pub fn fit_quality(problem: &Problem, theta: &[f64]) -> FitQuality {
    let mut per_observable = BTreeMap::new();
    let mut chi2 = 0.0;
    let mut n = 0;
    let mut per_observable_share = BTreeMap::new();
    for b in &problem.likelihood.blocks {
        let mut model_share = 0.0;
        let n_b = b.len();
        let mut eta = vec![0.0; n_b];
        problem.simulator.predict(b.model_index, &b.x, theta, &mut eta);
        let mut r: Vec<f64> = (0..n_b).map(|i| b.y[i] - eta[i]).collect();
        let c = if problem.simulator.has_model_covariance() || !b.diagonal_data() {
            let mut model = vec![0.0; n_b * n_b];
            problem.simulator.add_model_covariance(b.model_index, &b.x, theta, 1.0, &mut model);
            let mut ws = crate::engine::gp::CholeskyWorkspace::new(n_b);
            ws.factor.fill(0.0);
            b.add_data_covariance(1.0, &mut ws.factor);
            let data_diag: Vec<f64> = (0..n_b).map(|i| ws.factor[i * n_b + i]).collect();
            for (f, m) in ws.factor.iter_mut().zip(&model) {
                *f += m;
            }
            match ws.factorize() {
                Ok(_) => {
                    model_share += trace_of_product(&model, &ws.inverse(), n_b);
                    ws.solve_lower_in_place(&mut r);
                    r.iter().map(|z| z * z).sum()
                }
                Err(_) => {
                    model_share +=
                        (0..n_b).map(|i| model[i * n_b + i] / (model[i * n_b + i] + data_diag[i])).sum::<f64>();
                    f64::INFINITY
                }
            }
        } else {
            (0..n_b).map(|i| (r[i] / b.error[i]).powi(2)).sum()
        };
        per_observable.insert(b.name.clone(), c);
        per_observable_share.insert(b.name.clone(), model_share / n_b.max(1) as f64);
        chi2 += c;
        n += b.len();
    }
    // Joint: the χ² of all points together (the per-observable values stay each block's own).
    if let Some(total) = joint_chi2(problem, theta) {
        chi2 = total;
    }
    let dof = n.saturating_sub(theta.len()).max(1);
    let model_variance_share = worst_share(per_observable_share.values().copied());
    FitQuality {
        chi2,
        dof,
        chi2_per_dof: chi2 / dof as f64,
        per_observable,
        model_variance_share,
        per_observable_share,
    }
}

/// The largest share; one that is not a number (an emulator whose variance
/// is NaN or infinite) counts as 1, since nothing shows the fit rests on the
/// data (`f64::max` would silently drop it and call the fit data-driven).
fn worst_share(shares: impl Iterator<Item = f64>) -> f64 {
    shares.map(|v| if v.is_finite() { v } else { 1.0 }).fold(0.0, f64::max)
}

/// `tr(A B)` for symmetric n × n matrices, A given by its lower triangle and
/// B in full (both column-major).
fn trace_of_product(a_lower: &[f64], b: &[f64], n: usize) -> f64 {
    let mut t = 0.0;
    for j in 0..n {
        t += a_lower[j * n + j] * b[j * n + j];
        for i in j + 1..n {
            t += 2.0 * a_lower[j * n + i] * b[j * n + i];
        }
    }
    t
}

/// `rᵀ C⁻¹ r` over all points with the joint covariance of the data and the
/// model (no δ); `None` for the block form.
fn joint_chi2(problem: &Problem, theta: &[f64]) -> Option<f64> {
    let (lower, mut r) = problem.likelihood.joint_model_system(theta)?;
    let mut ws = crate::engine::gp::CholeskyWorkspace::new(r.len());
    ws.factor.copy_from_slice(&lower);
    Some(match ws.factorize() {
        Ok(_) => {
            ws.solve_lower_in_place(&mut r);
            r.iter().map(|z| z * z).sum()
        }
        Err(_) => f64::INFINITY,
    })
}

/// Posterior-predictive bands at one x for one observable.
#[derive(Clone, Debug, PartialEq)]
pub struct PredictionRow {
    pub observable: String,
    /// "grid" for the prediction grid, "data" at measured points.
    pub kind: &'static str,
    pub x: f64,
    /// Model alone η(x, θ): 2.5, 16, 50, 84, 97.5 percentiles.
    pub model: [f64; 5],
    /// Model + δ.
    pub model_md: [f64; 5],
    /// δ alone (original units) and its posterior mean.
    pub delta: [f64; 5],
    pub delta_mean: f64,
    /// The true curve (config `[truth]`), NaN where unknown.
    pub truth: f64,
}

const BAND_LEVELS: [f64; 5] = [0.025, 0.16, 0.5, 0.84, 0.975];

fn bands(values: &mut [f64]) -> [f64; 5] {
    values.sort_by(|a, b| a.total_cmp(b));
    BAND_LEVELS.map(|q| diagnostics::quantile_sorted(values, q))
}

/// Bands of η and η + δ on a grid extending beyond the data, and at the data.
/// δ at new x is drawn from the GP conditional on the residuals at the data;
/// pointwise bands need only its marginals.
pub fn predictions(problem: &Problem, chains: &Chains, seed: u64) -> Result<Vec<PredictionRow>> {
    let cfg = &problem.analysis.predictions;
    let lik = &problem.likelihood;
    let n_theta = lik.n_theta;
    let all: Vec<&[f64]> = chains.rows().collect();
    let n_use = cfg.draws.min(all.len()).max(1);
    let stride = all.len() as f64 / n_use as f64;
    let draws: Vec<&[f64]> = (0..n_use).map(|i| all[(i as f64 * stride) as usize]).collect();
    let mut rows = Vec::new();
    for (b, block) in lik.blocks.iter().enumerate() {
        let x_max = cfg.x_max.unwrap_or(1.5 * block.x.iter().cloned().fold(f64::NEG_INFINITY, f64::max));
        let x_min = cfg.x_min.unwrap_or(block.x.iter().cloned().fold(0.0, f64::min));
        let npts = cfg.points.max(2);
        // An emulator knows only its training bins: no grid then.
        let mut xs: Vec<(f64, &'static str)> = if problem.simulator.predicts_any_x() {
            (0..npts).map(|i| (x_min + (x_max - x_min) * i as f64 / (npts - 1) as f64, "grid")).collect()
        } else {
            Vec::new()
        };
        xs.extend(block.x.iter().map(|&x| (x, "data")));
        let xq: Vec<f64> = xs.iter().map(|p| p.0).collect();
        let m = xq.len();
        let truth = problem.analysis.truth_curve(&block.name, &xq).unwrap_or_else(|| vec![f64::NAN; m]);
        // Per draw: η(xq) and δ(xq) samples, in original units.
        let per_draw: Vec<(Vec<f64>, Vec<f64>, Vec<f64>)> = draws
            .par_iter()
            .enumerate()
            .map(|(d, params)| {
                let mut rng =
                    Xoshiro256PlusPlus::seed_from_u64(seed ^ ((b as u64) << 40) ^ (d as u64).wrapping_mul(0x9E37_79B9));
                let theta = &params[..n_theta];
                let mut eta = vec![0.0; m];
                problem.simulator.predict(block.model_index, &xq, theta, &mut eta);
                let (delta, delta_mean) = match lik.kernel {
                    None => (vec![0.0; m], vec![0.0; m]),
                    Some(kernel) => conditional_delta(kernel, params, b, &xq, problem, &mut rng),
                };
                (eta, delta, delta_mean)
            })
            .collect();
        for (q, &(x, kind)) in xs.iter().enumerate() {
            let mut model: Vec<f64> = per_draw.iter().map(|d| d.0[q]).collect();
            let mut md: Vec<f64> = per_draw.iter().map(|d| d.0[q] + d.1[q]).collect();
            let mut delta: Vec<f64> = per_draw.iter().map(|d| d.1[q]).collect();
            let delta_mean = per_draw.iter().map(|d| d.2[q]).sum::<f64>() / per_draw.len() as f64;
            rows.push(PredictionRow {
                observable: block.name.clone(),
                kind,
                x,
                model: bands(&mut model),
                model_md: bands(&mut md),
                delta: bands(&mut delta),
                delta_mean,
                truth: truth[q],
            });
        }
    }
    Ok(rows)
}

/// One draw of δ(xq) and its conditional mean, given the data residuals (of
/// every observable, when the likelihood is joint).
fn conditional_delta(
    kernel: DiscrepancyKernel,
    params: &[f64],
    b: usize,
    xq: &[f64],
    problem: &Problem,
    rng: &mut Xoshiro256PlusPlus,
) -> (Vec<f64>, Vec<f64>) {
    let lik = &problem.likelihood;
    let (block, hyper) = (&lik.blocks[b], lik.hyper_of(params, b));
    let m = xq.len();
    // The covariance of the standardized residuals, and where block b sits in it.
    let (lower, mut alpha, rows) = match lik.joint_system(params) {
        Some((lower, resid)) => (lower, resid, lik.joint.as_ref().map(|j| j.rows(b)).unwrap_or_default()),
        None => {
            let n = block.len();
            let theta = &params[..lik.n_theta];
            let mut eta = vec![0.0; n];
            problem.simulator.predict(block.model_index, &block.x, theta, &mut eta);
            let mut lower = vec![0.0; n * n];
            discrepancy_cross_cov(kernel, hyper, &block.kernel_x, &block.kernel_x, &mut lower);
            problem.simulator.add_model_covariance(
                block.model_index,
                &block.x,
                theta,
                1.0 / (block.scale * block.scale),
                &mut lower,
            );
            block.add_data_covariance(1.0 / (block.scale * block.scale), &mut lower);
            (lower, (0..n).map(|i| (block.y[i] - eta[i]) / block.scale).collect(), 0..n)
        }
    };
    let n = alpha.len();
    let mut ws = CholeskyWorkspace::new(n);
    ws.factor.copy_from_slice(&lower);
    if ws.factorize().is_err() {
        return (vec![f64::NAN; m], vec![f64::NAN; m]);
    }
    ws.solve_in_place(&mut alpha);
    // δ_b is correlated with block b's residuals only: zero elsewhere.
    let mut kq = vec![0.0; n];
    let mut draw = vec![0.0; m];
    let mut mean = vec![0.0; m];
    for q in 0..m {
        let kx = block.input.apply(xq[q]);
        kq.fill(0.0);
        discrepancy_cross_cov(kernel, hyper, &block.kernel_x, &[kx], &mut kq[rows.clone()]);
        let mu: f64 = kq.iter().zip(&alpha).map(|(a, b)| a * b).sum();
        ws.solve_lower_in_place(&mut kq);
        let prior_var = {
            let p = pow_r(kx, hyper[2]);
            let s2 = if kernel == DiscrepancyKernel::KernelI { hyper[3] * hyper[3] } else { 0.0 };
            s2 + hyper[0] * hyper[0] * p * p
        };
        let var = (prior_var - kq.iter().map(|v| v * v).sum::<f64>()).max(0.0);
        let z: f64 = StandardNormal.sample(rng);
        mean[q] = mu * block.scale;
        draw[q] = (mu + var.sqrt() * z) * block.scale;
    }
    (draw, mean)
}

pub fn predictions_frame(rows: &[PredictionRow]) -> Result<DataFrame> {
    let names = ["q025", "q16", "median", "q84", "q975"];
    let mut cols: Vec<Column> = vec![
        Column::new("observable".into(), rows.iter().map(|r| r.observable.as_str()).collect::<Vec<_>>()),
        Column::new("kind".into(), rows.iter().map(|r| r.kind).collect::<Vec<_>>()),
        Column::new("x".into(), rows.iter().map(|r| r.x).collect::<Vec<_>>()),
    ];
    for (prefix, get) in [
        ("model", (|r: &PredictionRow| r.model) as fn(&PredictionRow) -> [f64; 5]),
        ("model_md", |r: &PredictionRow| r.model_md),
        ("delta", |r: &PredictionRow| r.delta),
    ] {
        for (k, n) in names.iter().enumerate() {
            cols.push(Column::new(format!("{prefix}_{n}").into(), rows.iter().map(|r| get(r)[k]).collect::<Vec<_>>()));
        }
    }
    cols.push(Column::new("delta_mean".into(), rows.iter().map(|r| r.delta_mean).collect::<Vec<_>>()));
    cols.push(Column::new("truth".into(), rows.iter().map(|r| r.truth).collect::<Vec<_>>()));
    Ok(DataFrame::new(rows.len(), cols)?)
}

#[cfg(test)]
mod tests {
    use super::{trace_of_product, worst_share};
    use crate::engine::gp::CholeskyWorkspace;

    /// tr(M (M + D)⁻¹) from a lower triangle and a full inverse.
    fn share(model_lower: &[f64], data_diag: &[f64]) -> f64 {
        let n = data_diag.len();
        let mut ws = CholeskyWorkspace::new(n);
        ws.factor.copy_from_slice(model_lower);
        for i in 0..n {
            ws.factor[i * n + i] += data_diag[i];
        }
        ws.factorize().unwrap();
        trace_of_product(model_lower, &ws.inverse(), n)
    }

    #[test]
    fn a_share_that_is_not_a_number_counts_as_the_emulator_deciding() {
        assert_eq!(worst_share([0.2, 0.4].into_iter()), 0.4);
        assert_eq!(worst_share([0.2, f64::NAN].into_iter()), 1.0);
        assert_eq!(worst_share([f64::INFINITY].into_iter()), 1.0);
        assert_eq!(worst_share(std::iter::empty()), 0.0);
    }

    #[test]
    fn independent_points_share_is_the_sum_of_their_fractions() {
        let (m, d) = ([4.0, 1.0, 0.25], [1.0, 1.0, 4.0]);
        let mut lower = vec![0.0; 9];
        for i in 0..3 {
            lower[i * 3 + i] = m[i];
        }
        let want: f64 = (0..3).map(|i| m[i] / (m[i] + d[i])).sum();
        assert!((share(&lower, &d) - want).abs() < 1e-12);
    }

    #[test]
    fn correlated_share_does_not_change_with_the_units_of_the_data() {
        // M = a aᵀ + 0.1 I (a fully shared component plus a little of each point's own).
        let a = [1.0, 0.5, -0.3];
        let mut lower = vec![0.0; 9];
        for j in 0..3 {
            for i in j..3 {
                lower[j * 3 + i] = a[i] * a[j] + if i == j { 0.1 } else { 0.0 };
            }
        }
        let d = [0.2, 0.3, 0.5];
        let base = share(&lower, &d);
        // Each point in its own units (a map S = diag(s)): M → S M S, D → S D S.
        let s = [1.0, 1e3, 1e-2];
        let scaled: Vec<f64> = (0..9).map(|k| lower[k] * s[k / 3] * s[k % 3]).collect();
        let d_scaled: Vec<f64> = (0..3).map(|i| d[i] * s[i] * s[i]).collect();
        assert!((share(&scaled, &d_scaled) - base).abs() < 1e-9 * base);
        // A ratio of summed variances is not invariant: the point in large
        // units outvotes the others (0.621 becomes 0.538, its own fraction).
        let summed = |m: &[f64], d: &[f64]| {
            (0..3).map(|i| m[i * 3 + i]).sum::<f64>() / (0..3).map(|i| m[i * 3 + i] + d[i]).sum::<f64>()
        };
        assert!((summed(&lower, &d) - 1.64 / 2.64).abs() < 1e-12);
        assert!((summed(&scaled, &d_scaled) - 0.35 / 0.65).abs() < 1e-3);
        assert!(base > 0.0 && base < 3.0, "{base}");
    }
}
