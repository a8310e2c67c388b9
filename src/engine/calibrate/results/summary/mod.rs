//! Posterior summaries (`summary.json`) and posterior-predictive bands
//! (`predictions.parquet`).

use crate::base::artifacts::Provenance;
use crate::engine::calibrate::problem::Problem;
use crate::engine::calibrate::sampler::chains::Chains;
use crate::engine::calibrate::sampler::diagnostics::{self, ParamDiagnostics};
use crate::engine::calibrate::sampler::smc::{SmcOutput, SmcStep};
use crate::engine::gp::{discrepancy_cross_cov, pow_r, CholeskyWorkspace, DiscrepancyKernel};
use crate::engine::model::Units;
use anyhow::Result;
use polars::prelude::*;
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use rand_xoshiro::Xoshiro256PlusPlus;
use rayon::prelude::*;
use std::collections::BTreeMap;

mod edges;
mod fit;
mod predictions;
mod replicates;

pub use edges::{piled_at_bounds, PiledAtBound};
pub use fit::*;
pub use predictions::*;
pub use replicates::*;

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

/// A value as a person reads it: three decimals where that keeps three
/// significant figures' worth (0.001 to 10⁶), else scientific notation, so
/// a dead time of 2.4e-6 s does not print as 0.000.
pub fn readable(v: f64) -> String {
    if v == 0.0 || !v.is_finite() || (1e-3..1e6).contains(&v.abs()) {
        format!("{v:.3}")
    } else {
        format!("{v:.3e}")
    }
}

impl ParamSummary {
    /// `median [q025, q975]`, each `readable`.
    pub fn interval(&self) -> String {
        format!("{} [{}, {}]", readable(self.median), readable(self.q025), readable(self.q975))
    }

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
        /// The highest β at which a replicate stopped because its final log
        /// evidence could not reach what was asked (`smc::Abandon`): the
        /// draws are then of the tempered posterior at β and the log
        /// evidence an upper estimate.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        abandoned_at: Option<f64>,
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
    /// The independent proposals' acceptance (from a mixture fitted to the cloud).
    #[serde(default)]
    pub mixture_acceptance: f64,
}

impl From<&SmcStep> for SmcStepRecord {
    fn from(s: &SmcStep) -> Self {
        SmcStepRecord {
            beta: s.beta,
            mcmc_steps: s.mcmc_steps,
            acceptance: s.acceptance,
            group_acceptance: s.group_acceptance.clone(),
            mixture_acceptance: s.mixture_acceptance,
        }
    }
}

impl SamplerDetails {
    pub fn from_smc(out: &SmcOutput) -> Self {
        SamplerDetails::Smc {
            replicates: out.replicates.len(),
            particles_per_replicate: out.chains.n_draws() / out.chains.chains.len().max(1),
            replicate_log_evidence: out.replicates.iter().map(|r| r.log_evidence).collect(),
            tempering_steps: out.replicates.iter().map(|r| r.steps.len()).collect(),
            schedule: out
                .replicates
                .first()
                .map(|r| r.steps.iter().map(SmcStepRecord::from).collect())
                .unwrap_or_default(),
            unique_fraction: out.replicates.iter().map(|r| r.unique_fraction).collect(),
            term_evaluations: out.replicates.iter().map(|r| r.term_evaluations).sum(),
            abandoned_at: out.abandoned_at(),
        }
    }

    /// Where an SMC run was abandoned (`smc::Abandon`), if it was.
    pub fn abandoned_at(&self) -> Option<f64> {
        match self {
            SamplerDetails::Smc { abandoned_at, .. } => *abandoned_at,
            SamplerDetails::Ensemble { .. } => None,
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
    /// Every run, when the first did not converge and was sampled again
    /// with more (`calibrate::sampler::adapt`); absent otherwise.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub adaptation: Vec<crate::engine::calibrate::sampler::adapt::Attempt>,
}

impl Diagnostics {
    /// Records the runs of an adapted calibration, and says so among the
    /// warnings when even the last did not converge.
    pub fn note_adaptation(&mut self, attempts: Vec<crate::engine::calibrate::sampler::adapt::Attempt>) {
        if attempts.len() > 1 && !self.converged {
            let last = &attempts[attempts.len() - 1];
            self.warnings.push(format!(
                "not converged after {} runs (the last with {} particles per replicate and {} final sweeps per dimension)",
                attempts.len(),
                last.particles,
                last.final_steps_per_dim
            ));
        }
        self.adaptation = attempts;
    }

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
    /// Parameters whose draws pile against a bound of the prior box
    /// (`edges`): the box, not the data, ends the posterior there.
    #[serde(default)]
    pub piled_at_bounds: Vec<PiledAtBound>,
    /// How the model computed where it chose from the data (a declared
    /// ODE's tolerances), so that a fit says what it was made with.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub numerics: Option<String>,
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
    if let Some(beta) = sampler.abandoned_at() {
        warnings.push(format!(
            "stopped tempering at β = {beta:.2e}: its final log evidence could not reach what was asked, so the draws are of the tempered posterior and the log evidence an upper estimate"
        ));
    }
    // With no parameters every draw is the one point: as good as independent.
    let min_ess = match per_param.iter().map(|d| d.ess_bulk.min(d.ess_tail)).reduce(f64::min) {
        Some(ess) => ess,
        None => chains.n_draws() as f64,
    };
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
            adaptation: Vec::new(),
        },
        piled_at_bounds: piled_at_bounds(chains, &problem.prior, problem.likelihood.n_theta),
        numerics: problem.simulator.numerics(),
        provenance: problem.provenance(seed, "calibrate"),
    }
}

#[cfg(test)]
mod readable_tests {
    use super::readable;

    #[test]
    fn small_and_large_values_keep_their_figures() {
        assert_eq!(readable(2.346), "2.346");
        assert_eq!(readable(49679.906), "49679.906");
        assert_eq!(readable(2.418e-6), "2.418e-6");
        assert_eq!(readable(0.0), "0.000");
        assert_eq!(readable(-3.2e7), "-3.200e7");
    }
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
