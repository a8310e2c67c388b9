//! MD-augmented Bayesian calibration: the likelihood, priors, the two
//! samplers, their diagnostics, and the `calibrate`/`compare` stages.
//!
//! A sampler sees a calibration problem as a [`UniformPrior`] and a
//! [`LogLikelihood`]; [`Problem`] builds both from a config and data.

pub mod checkpoint;
pub mod compare;
pub mod diagnostics;
pub mod ensemble;
pub mod likelihood;
pub mod prior;
pub mod smc;
pub mod summary;

use crate::artifacts::{self, Measurement, Provenance};
use crate::config::{Config, ModelConfig, SamplerKind};
use crate::gp::DiscrepancyKernel;
use crate::models::{BallDropModel, Simulator};
use anyhow::{anyhow, bail, Context, Result};
pub use likelihood::{MdLikelihood, ObservableBlock};
pub use prior::UniformPrior;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Anything a sampler can target, given a uniform prior.
pub trait LogLikelihood: Sync {
    fn log_likelihood(&self, x: &[f64]) -> f64;

    /// How the log-likelihood splits into independent terms, when it does; a
    /// sampler may then move one term's own parameters at the cost of that term.
    fn term_structure(&self) -> Option<TermStructure> {
        None
    }

    /// The log-likelihood, with each term written to `terms` (only called when
    /// `term_structure` is given).
    fn log_likelihood_terms(&self, x: &[f64], _terms: &mut [f64]) -> f64 {
        self.log_likelihood(x)
    }

    /// One term (only called when `term_structure` is given).
    fn log_likelihood_term(&self, _x: &[f64], _term: usize) -> f64 {
        unreachable!("log_likelihood_term needs a term structure")
    }
}

/// `log L(x) = const + Σ_t L_t(x_shared, x_own(t))`: every term depends on the
/// shared parameters (θ) and on its own (one observable's φ), and on no other.
#[derive(Clone, Debug)]
pub struct TermStructure {
    pub shared: Vec<usize>,
    pub own: Vec<Vec<usize>>,
}

impl LogLikelihood for MdLikelihood {
    fn log_likelihood(&self, x: &[f64]) -> f64 {
        MdLikelihood::log_likelihood(self, x)
    }
    fn term_structure(&self) -> Option<TermStructure> {
        let nh = self.n_hyper();
        if nh == 0 {
            return None;
        }
        let own = (0..self.blocks.len()).map(|b| (self.n_theta + b * nh..self.n_theta + (b + 1) * nh).collect()).collect();
        Some(TermStructure { shared: (0..self.n_theta).collect(), own })
    }
    fn log_likelihood_terms(&self, x: &[f64], terms: &mut [f64]) -> f64 {
        MdLikelihood::log_likelihood_terms(self, x, terms)
    }
    fn log_likelihood_term(&self, x: &[f64], term: usize) -> f64 {
        MdLikelihood::log_likelihood_term(self, x, term)
    }
}

/// Posterior draws grouped into chains (walkers for the ensemble sampler,
/// replicates for SMC). Each chain is row-major `draws × dim`.
#[derive(Clone, Debug)]
pub struct Chains {
    pub names: Vec<String>,
    pub dim: usize,
    pub chains: Vec<Vec<f64>>,
}

impl Chains {
    pub fn n_draws(&self) -> usize {
        self.chains.iter().map(|c| c.len() / self.dim).sum()
    }

    /// Per-chain series of parameter `p`.
    pub fn param_chains(&self, p: usize) -> Vec<Vec<f64>> {
        self.chains.iter().map(|c| c.chunks(self.dim).map(|row| row[p]).collect()).collect()
    }

    /// All draws of parameter `p`.
    pub fn param(&self, p: usize) -> Vec<f64> {
        self.chains.iter().flat_map(|c| c.chunks(self.dim).map(move |row| row[p])).collect()
    }

    /// All draws as rows.
    pub fn rows(&self) -> impl Iterator<Item = &[f64]> {
        self.chains.iter().flat_map(move |c| c.chunks(self.dim))
    }
}

/// Choices that override the config from the command line.
#[derive(Clone, Debug, Default)]
pub struct Overrides {
    pub data: Option<PathBuf>,
    pub kernel: Option<Option<DiscrepancyKernel>>,
    pub observables: Option<Vec<String>>,
    pub sampler: Option<SamplerKind>,
}

/// A fully specified calibration: model, data, likelihood and prior.
pub struct Problem {
    pub config: Config,
    pub data_path: PathBuf,
    pub measurements: Vec<Measurement>,
    pub simulator: Arc<dyn Simulator>,
    pub likelihood: MdLikelihood,
    pub prior: UniformPrior,
    pub sampler: SamplerKind,
}

pub fn build_simulator(config: &Config) -> Result<Arc<dyn Simulator>> {
    Ok(match &config.model {
        ModelConfig::BallDrop { h0 } => Arc::new(BallDropModel { h0: *h0 }),
        ModelConfig::Emulator { artifact } => Arc::new(
            crate::models::EmulatedModel::load(&config.resolve(artifact)).with_context(|| format!("{}: [model] artifact", config.path.display()))?,
        ),
    })
}

impl Problem {
    pub fn new(config: &Config, overrides: &Overrides) -> Result<Problem> {
        let simulator = build_simulator(config)?;
        Self::with_simulator(config, overrides, simulator)
    }

    /// Builds the problem around a given simulator (used by `diagnose` for
    /// candidate-augmented models).
    pub fn with_simulator(config: &Config, overrides: &Overrides, simulator: Arc<dyn Simulator>) -> Result<Problem> {
        let data_path = match &overrides.data {
            Some(p) => p.clone(),
            None => config.resolve(&config.data.measurements),
        };
        let measurements = artifacts::read_measurements(&data_path)?;
        let kernel = match overrides.kernel {
            Some(k) => k,
            None => config.discrepancy.kernel()?,
        };
        let model_obs = simulator.observable_names();
        // Every row must belong to an observable the model knows, so that a
        // misspelt name is an error, never silently dropped data.
        for m in &measurements {
            if !model_obs.contains(&m.observable) {
                bail!(
                    "{}, field 'observable': unknown observable '{}' (model '{}' predicts: {})",
                    m.location(&data_path),
                    m.observable,
                    config.name,
                    model_obs.join(", ")
                );
            }
        }
        let selected: Vec<String> = match (&overrides.observables, &config.data.observables) {
            (Some(o), _) | (None, Some(o)) => o.clone(),
            (None, None) => model_obs.iter().filter(|o| measurements.iter().any(|m| &m.observable == *o)).cloned().collect(),
        };
        if selected.is_empty() {
            bail!("no observables selected");
        }
        let mut blocks = Vec::new();
        for name in &selected {
            let idx = model_obs
                .iter()
                .position(|o| o == name)
                .ok_or_else(|| anyhow!("unknown observable '{name}' requested (model predicts: {})", model_obs.join(", ")))?;
            let rows: Vec<&Measurement> = measurements.iter().filter(|m| &m.observable == name).collect();
            if rows.is_empty() {
                bail!("{}: no measurements of observable '{name}'", data_path.display());
            }
            let block = ObservableBlock::new(name, idx, &rows).with_context(|| data_path.display().to_string())?;
            simulator.check_inputs(idx, &block.x).with_context(|| data_path.display().to_string())?;
            blocks.push(block);
        }
        let likelihood = MdLikelihood::new(simulator.clone(), blocks, kernel);

        let mut lower = Vec::new();
        let mut upper = Vec::new();
        let theta_names = simulator.parameter_names();
        for name in &theta_names {
            let spec = config
                .parameters
                .get(name)
                .ok_or_else(|| anyhow!("{}: [parameters] has no bounds for model parameter '{name}'", config.path.display()))?;
            lower.push(spec.min);
            upper.push(spec.max);
        }
        for name in config.parameters.keys() {
            if !theta_names.contains(name) {
                bail!("{}: [parameters.{name}]: the model has no parameter '{name}' (it has: {})", config.path.display(), theta_names.join(", "));
            }
        }
        if let Some(k) = kernel {
            for _ in &likelihood.blocks {
                for h in k.hyper_names() {
                    let b = config.hyper_bounds(h)?;
                    lower.push(b[0]);
                    upper.push(b[1]);
                }
            }
        }
        let prior = UniformPrior::new(likelihood.parameter_names(), lower, upper)?;
        Ok(Problem {
            config: Config {
                // `[truth]` describes the config's own data file, not a --data replacement.
                truth: if overrides.data.is_some() { None } else { config.truth.clone() },
                ..config.clone()
            },
            data_path,
            measurements,
            simulator,
            likelihood,
            prior,
            sampler: overrides.sampler.unwrap_or(config.sampler.kind),
        })
    }

    pub fn observables(&self) -> Vec<String> {
        self.likelihood.blocks.iter().map(|b| b.name.clone()).collect()
    }

    pub fn provenance(&self, seed: u64, command: &str) -> Provenance {
        Provenance::new(self.config.hash.clone(), artifacts::measurements_hash(&self.measurements), seed, command)
    }
}

/// Output of one calibration run, in memory.
pub struct Calibration {
    pub chains: Chains,
    pub summary: summary::Summary,
    pub predictions: Vec<summary::PredictionRow>,
}

/// Runs the configured sampler and summarizes the result.
pub fn run(problem: &Problem, seed: u64, show_progress: bool) -> Result<Calibration> {
    run_checkpointed(problem, seed, show_progress, None)
}

/// Identifies a calibration for its checkpoints: config, data, kernel,
/// observables, prior, sampler settings and seed.
pub fn checkpoint_key(problem: &Problem, seed: u64) -> String {
    let material = format!(
        "{}|{}|{seed}|{}|{:?}|{:?}|{:?}|{:?}|{:?}",
        problem.config.hash,
        artifacts::measurements_hash(&problem.measurements),
        DiscrepancyKernel::label(problem.likelihood.kernel),
        problem.observables(),
        problem.prior.names,
        problem.prior.lower,
        problem.prior.upper,
        problem.config.sampler.smc
    );
    artifacts::sha256_hex(material.as_bytes())
}

/// As `run`; with `checkpoint` the SMC sampler saves its state as it goes,
/// resumes from a matching saved state, and clears it when done. Stopped at
/// the checkpoint's time limit it returns a `checkpoint::Stopped` error.
pub fn run_checkpointed(problem: &Problem, seed: u64, show_progress: bool, checkpoint: Option<&checkpoint::Checkpointing>) -> Result<Calibration> {
    let start = std::time::Instant::now();
    let jitter_before = crate::gp::jitter_events();
    let label = format!("{} kernel={} obs={}", problem.config.name, DiscrepancyKernel::label(problem.likelihood.kernel), problem.observables().join("+"));
    let (chains, evidence, sampler_details, evaluations) = match problem.sampler {
        SamplerKind::Smc => {
            let settings = problem.config.sampler.smc.clone();
            let pb = show_progress.then(|| crate::progress_bar(1000 * settings.replicates as u64, &format!("SMC {label}")));
            let out = smc::Smc::new(settings).run_checkpointed(&problem.prior, &problem.likelihood, seed, pb.as_ref(), checkpoint);
            if let Some(pb) = pb {
                pb.finish_and_clear();
            }
            let out = out?;
            if let Some(c) = checkpoint {
                c.clear();
            }
            let evals = out.likelihood_evaluations();
            let details = summary::SamplerDetails::from_smc(&out);
            (out.chains, Some((out.log_evidence, out.log_evidence_err)), details, evals)
        }
        SamplerKind::Ensemble => {
            let settings = problem.config.sampler.ensemble.clone();
            let pb = show_progress.then(|| crate::progress_bar((settings.burn + settings.steps) as u64, &format!("ensemble {label}")));
            let out = ensemble::Ensemble::new(settings).run(&problem.prior, &problem.likelihood, seed, pb.as_ref());
            if let Some(pb) = pb {
                pb.finish_and_clear();
            }
            let details = summary::SamplerDetails::Ensemble { walkers: out.chains.chains.len(), acceptance: out.acceptance };
            (out.chains, None, details, out.likelihood_evaluations)
        }
    };
    let wall = start.elapsed().as_secs_f64();
    let jitter = crate::gp::jitter_events() - jitter_before;
    let summary = summary::summarize(problem, &chains, evidence, sampler_details, evaluations, wall, jitter, seed);
    let predictions = summary::predictions(problem, &chains, seed)?;
    Ok(Calibration { chains, summary, predictions })
}

/// Writes `posterior.parquet`, `summary.json` and `predictions.parquet` into `dir`.
pub fn write_outputs(dir: &Path, problem: &Problem, cal: &Calibration) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let prov = &cal.summary.provenance;
    let mut cols: Vec<(String, Vec<f64>)> = (0..cal.chains.dim).map(|p| (cal.chains.names[p].clone(), cal.chains.param(p))).collect();
    // Which chain each draw came from, so diagnostics can be recomputed.
    let chain_ids: Vec<f64> = cal.chains.chains.iter().enumerate().flat_map(|(k, c)| std::iter::repeat_n(k as f64, c.len() / cal.chains.dim)).collect();
    cols.push(("chain".into(), chain_ids));
    let mut df = artifacts::f64_frame(cols)?;
    artifacts::write_parquet_atomic(&dir.join("posterior.parquet"), &mut df, Some(prov))?;
    artifacts::write_json_atomic(&dir.join("summary.json"), &cal.summary)?;
    let mut pred = summary::predictions_frame(&cal.predictions)?;
    artifacts::write_parquet_atomic(&dir.join("predictions.parquet"), &mut pred, Some(prov))?;
    // The measurements fitted, so that reports and re-analyses need nothing else.
    let used: Vec<Measurement> = problem.measurements.iter().filter(|m| problem.observables().contains(&m.observable)).cloned().collect();
    artifacts::write_measurements(&dir.join("measurements.parquet"), &used, Some(prov))?;
    Ok(())
}
