//! MD-augmented Bayesian calibration: the likelihood, priors, the two
//! samplers, their diagnostics, and the `calibrate`/`compare` stages.
//!
//! A sampler sees a calibration problem as a [`UniformPrior`] and a
//! [`LogLikelihood`]; [`Problem`] builds both from an [`Analysis`] (a config
//! resolved once) and data.

pub mod across;
pub mod adapt;
pub mod algorithm;
pub mod analysis;
pub mod block;
pub mod block_stats;
pub mod checkpoint;
pub mod data_covariance;
pub mod diagnostics;
pub mod ensemble;
pub mod fisher;
pub mod guard;
pub mod joint;
pub mod likelihood;
pub mod prior;
pub mod settings;
pub mod smc;
pub mod stored;
pub mod structured;
pub mod structured_model;
pub mod summary;
pub mod target;

use crate::base::artifacts::{self, Measurement, Provenance};
use crate::base::choices::Kernel;
use crate::base::config::KernelInput;
use crate::base::progress::Observer;
use crate::engine::gp::DiscrepancyKernel;
use crate::engine::model::Simulator;
pub use analysis::Analysis;
use anyhow::{anyhow, bail, Context, Result};
pub use block::ObservableBlock;
pub use likelihood::MdLikelihood;
pub use prior::UniformPrior;
pub use settings::{SamplerConfig, SamplerKind};
use std::path::{Path, PathBuf};
use std::sync::Arc;
pub use target::{LogLikelihood, SeparableTerms, TermStatistics, TermStructure};

/// Posterior draws grouped into chains (walkers for the ensemble sampler,
/// replicates for SMC). Each chain is row-major `draws × dim`.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Chains {
    pub names: Vec<String>,
    pub dim: usize,
    #[serde(with = "checkpoint::f64_bits_rows")]
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
    /// The kernel, `Kernel::None` for the fit without MD; `None` keeps the config's.
    pub kernel: Option<Kernel>,
    pub observables: Option<Vec<String>>,
    pub sampler: Option<SamplerKind>,
}

/// A fully specified calibration: the analysis, its data, likelihood and prior.
pub struct Problem {
    /// The analysis as resolved from its config (without `truth` when
    /// `--data` replaced the data the truth describes).
    pub analysis: Analysis,
    pub data_path: PathBuf,
    pub measurements: Vec<Measurement>,
    pub simulator: Arc<dyn Simulator>,
    pub likelihood: MdLikelihood,
    pub prior: UniformPrior,
    pub sampler: SamplerKind,
}

/// The HEPData record `data_path` names, read as `[data.hepdata]` says
/// (bins without a value skipped, and said so); `None` for other formats.
fn hepdata_record(analysis: &Analysis, data_path: &Path) -> Result<Option<crate::base::hepdata::Record>> {
    if !crate::base::hepdata::is_hepdata(data_path) {
        return Ok(None);
    }
    if let Some(covariance) = &analysis.covariance {
        bail!(
            "{}: [data] covariance ({}) with HEPData measurements: their systematics already make the covariance; give one or the other",
            analysis.config_path.display(),
            covariance.display()
        );
    }
    let mut record = crate::base::hepdata::read(data_path, &analysis.hepdata)?;
    // A published record holds every class; the model predicts some of them.
    let predicted = analysis.simulator.observable_names();
    let mut unused: Vec<String> =
        record.points.iter().map(|p| p.observable.clone()).filter(|o| !predicted.contains(o)).collect();
    unused.dedup();
    if !unused.is_empty() {
        record.points.retain(|p| predicted.contains(&p.observable));
        crate::base::messages::note!(
            "note: {}: not predicted by the model, so not used: {} (name them in [data.hepdata] observables to use them)",
            data_path.display(),
            unused.join(", ")
        );
    }
    if record.points.is_empty() {
        bail!("{}: none of its dependent variables is an observable of the model", data_path.display());
    }
    if !record.skipped.is_empty() {
        crate::base::messages::note!(
            "note: {}: {} bin(s) without a value (null or '-') skipped",
            data_path.display(),
            record.skipped.len()
        );
    }
    Ok(Some(record))
}

impl Problem {
    pub fn new(analysis: &Analysis, overrides: &Overrides) -> Result<Problem> {
        let simulator = analysis.simulator.clone();
        let data_path = overrides.data.clone().unwrap_or_else(|| analysis.data.clone());
        let hepdata = hepdata_record(analysis, &data_path)?;
        let measurements = match &hepdata {
            Some(record) => record.measurements(),
            None => artifacts::read_measurements(&data_path)?,
        };
        let kernel = overrides.kernel.map_or(analysis.kernel, DiscrepancyKernel::of);
        check_observables_known(analysis, &simulator, &measurements, &data_path)?;
        let selected: Vec<String> = match (&overrides.observables, &analysis.observables) {
            (Some(o), _) | (None, Some(o)) => o.clone(),
            (None, None) => simulator
                .observable_names()
                .into_iter()
                .filter(|o| measurements.iter().any(|m| &m.observable == o))
                .collect(),
        };
        let mut blocks: Vec<ObservableBlock> = observable_blocks(&simulator, &selected, &measurements, &data_path)?
            .into_iter()
            .map(|b| {
                let input =
                    analysis.kernel_inputs.get(&b.name).copied().unwrap_or_else(|| KernelInput::scaled_to(&b.x));
                b.with_kernel_input(input)
            })
            .collect();
        let across = match (&analysis.covariance, &overrides.data) {
            _ if hepdata.is_some() => {
                let entries = hepdata.as_ref().map(|r| r.covariance(&analysis.hepdata)).unwrap_or_default();
                data_covariance::attach(&mut blocks, &entries, &measurements, &data_path, &data_path)?
            }
            (Some(path), None) => {
                let entries = data_covariance::read(path)
                    .with_context(|| format!("{}: [data] covariance", analysis.config_path.display()))?;
                data_covariance::attach(&mut blocks, &entries, &measurements, path, &data_path)?
            }
            (Some(path), Some(_)) => {
                crate::base::messages::note!("warning: --data replaces the config's measurements; the config's [data] covariance ({}) describes those and is not used", path.display());
                Vec::new()
            }
            (None, _) => Vec::new(),
        };
        let spans = simulator.has_model_covariance() && simulator.model_covariance_spans_observables();
        if !across.is_empty() && analysis.between_observables == crate::base::config::BetweenObservables::Independent {
            crate::base::messages::note!("warning: {} covariance entries between observables are not used: [data] between_observables = \"independent\"", across.len());
        }
        let mut likelihood = MdLikelihood::new(simulator.clone(), blocks, kernel);
        if joint::wanted(analysis.between_observables, likelihood.blocks.len(), across.len(), spans) {
            likelihood = likelihood.joint(&across);
        }
        let prior = prior_of(analysis, &likelihood)?;
        let sampler = overrides.sampler.unwrap_or(analysis.sampler.kind);
        let mut analysis = analysis.clone();
        if overrides.data.is_some() {
            // `[truth]` describes the config's own data file, not a --data replacement.
            analysis.truth = None;
        }
        Ok(Problem { analysis, data_path, measurements, simulator, likelihood, prior, sampler })
    }

    pub fn observables(&self) -> Vec<String> {
        self.likelihood.blocks.iter().map(|b| b.name.clone()).collect()
    }

    pub fn provenance(&self, seed: u64, command: &str) -> Provenance {
        Provenance::new(
            self.analysis.config_hash.clone(),
            artifacts::measurements_hash(&self.measurements),
            seed,
            command,
        )
    }
}

/// Every row must belong to an observable the model knows, so that a
/// misspelt name is an error, never silently dropped data.
fn check_observables_known(
    analysis: &Analysis,
    simulator: &Arc<dyn Simulator>,
    measurements: &[Measurement],
    data_path: &Path,
) -> Result<()> {
    let model_obs = simulator.observable_names();
    if let Some(m) = measurements.iter().find(|m| !model_obs.contains(&m.observable)) {
        let problem = format!(
            "unknown observable '{}' (model '{}' predicts: {})",
            m.observable,
            analysis.name,
            model_obs.join(", ")
        );
        return Err(m.field_error(data_path, "observable", problem));
    }
    Ok(())
}

/// One standardized block per selected observable, checked against the model.
fn observable_blocks(
    simulator: &Arc<dyn Simulator>,
    selected: &[String],
    measurements: &[Measurement],
    data_path: &Path,
) -> Result<Vec<ObservableBlock>> {
    if selected.is_empty() {
        bail!("no observables selected");
    }
    let model_obs = simulator.observable_names();
    let mut blocks = Vec::new();
    for name in selected {
        let idx = model_obs.iter().position(|o| o == name).ok_or_else(|| {
            anyhow!("unknown observable '{name}' requested (model predicts: {})", model_obs.join(", "))
        })?;
        let rows: Vec<&Measurement> = measurements.iter().filter(|m| &m.observable == name).collect();
        if rows.is_empty() {
            bail!("{}: no measurements of observable '{name}'", data_path.display());
        }
        let block = ObservableBlock::new(name, idx, &rows).with_context(|| data_path.display().to_string())?;
        simulator.check_inputs(idx, &block.x).with_context(|| data_path.display().to_string())?;
        blocks.push(block);
    }
    Ok(blocks)
}

/// Uniform prior over θ (the analysis' bounds, in the model's order) and
/// each block's discrepancy hyperparameters.
fn prior_of(analysis: &Analysis, likelihood: &MdLikelihood) -> Result<UniformPrior> {
    let file = analysis.config_path.display();
    let theta_names = likelihood.simulator.parameter_names();
    let (mut lower, mut upper) = (Vec::new(), Vec::new());
    for name in &theta_names {
        let spec = analysis
            .parameters
            .get(name)
            .ok_or_else(|| anyhow!("{file}: [parameters] has no bounds for model parameter '{name}'"))?;
        lower.push(spec.min);
        upper.push(spec.max);
    }
    if let Some(name) = analysis.parameters.keys().find(|n| !theta_names.contains(n)) {
        bail!("{file}: [parameters.{name}]: the model has no parameter '{name}' (it has: {})", theta_names.join(", "));
    }
    if let Some(k) = likelihood.kernel {
        for _ in &likelihood.blocks {
            for h in k.hyper_names() {
                let b = analysis.hyper_bounds(h)?;
                lower.push(b[0]);
                upper.push(b[1]);
            }
        }
    }
    UniformPrior::new(likelihood.parameter_names(), lower, upper)
}

/// Output of one calibration run, in memory.
#[derive(Clone)]
pub struct Calibration {
    pub chains: Chains,
    pub summary: summary::Summary,
    pub predictions: Vec<summary::PredictionRow>,
}

/// Runs the configured sampler and summarizes the result.
pub fn run(problem: &Problem, seed: u64, observer: &dyn Observer) -> Result<Calibration> {
    run_checkpointed(problem, seed, observer, None)
}

/// Whether sampling a calibration again for convergence can still matter
/// to whoever asked for it, given its log evidence and that estimate's
/// error: a candidate so far behind the leader that no convergence could
/// bring it within reach, or one weighed only by its evidence, is not
/// sampled again to chase R̂ and ESS (`run_smc_until_converged`).
pub type Matters<'a> = &'a (dyn Fn(f64, f64) -> bool + Sync);

/// As `run`, sampling again for convergence only while `matters` says the
/// answer can still change a decision.
pub fn run_judged(problem: &Problem, seed: u64, observer: &dyn Observer, matters: Matters) -> Result<Calibration> {
    sample(problem, seed, observer, None, matters)
}

/// Identifies a calibration for its checkpoints: config, data, kernel,
/// observables, prior, sampler settings and seed.
pub fn checkpoint_key(problem: &Problem, seed: u64) -> String {
    let material = format!(
        "{}|{}|{seed}|{}|{:?}|{:?}|{:?}|{:?}|{:?}|{:?}",
        problem.analysis.config_hash,
        artifacts::measurements_hash(&problem.measurements),
        DiscrepancyKernel::label(problem.likelihood.kernel),
        problem.observables(),
        problem.prior.names,
        problem.prior.lower,
        problem.prior.upper,
        problem.analysis.sampler.smc,
        // The data's covariance beyond the errors, the joint form and the
        // discrepancy's inputs change the likelihood too.
        (
            problem
                .likelihood
                .blocks
                .iter()
                .map(|b| (b.input.shift.to_bits(), b.input.scale.to_bits()))
                .collect::<Vec<_>>(),
            problem
                .likelihood
                .blocks
                .iter()
                .map(|b| b.covariance.as_ref().map(|c| c.iter().map(|v| v.to_bits()).collect::<Vec<u64>>()))
                .collect::<Vec<_>>(),
            problem
                .likelihood
                .joint
                .as_ref()
                .map(|j| (j.data.iter().map(|v| v.to_bits()).collect::<Vec<u64>>(), j.model_spans))
        )
    );
    artifacts::sha256_hex(material.as_bytes())
}

/// What a sampler returns, in the form the summary needs.
struct Sampled {
    chains: Chains,
    evidence: Option<(f64, f64)>,
    details: summary::SamplerDetails,
    evaluations: u64,
    /// Every run when the first did not converge (`adapt`); empty otherwise.
    adaptation: Vec<adapt::Attempt>,
}

/// Calibrates with checkpoints in `checkpoint`, writes the outputs into
/// `dir`, and only then clears the checkpoint: a failed write (a full disk)
/// keeps the sampled state, and the same command finishes from it.
pub fn run_and_write(
    problem: &Problem,
    seed: u64,
    observer: &dyn Observer,
    checkpoint: &checkpoint::Checkpointing,
    dir: &Path,
) -> Result<Calibration> {
    let cal = run_checkpointed(problem, seed, observer, Some(checkpoint))?;
    write_outputs(dir, problem, &cal)?;
    checkpoint.clear();
    Ok(cal)
}

/// As `run`; with `checkpoint` the SMC sampler saves its state as it goes and
/// resumes from a matching saved state (the caller clears it once the
/// outputs are safe: [`run_and_write`]). Stopped at the checkpoint's time
/// limit it returns a `algorithm::Stopped` error.
pub fn run_checkpointed(
    problem: &Problem,
    seed: u64,
    observer: &dyn Observer,
    checkpoint: Option<&checkpoint::Checkpointing>,
) -> Result<Calibration> {
    sample(problem, seed, observer, checkpoint, &|_, _| true)
}

fn sample(
    problem: &Problem,
    seed: u64,
    observer: &dyn Observer,
    checkpoint: Option<&checkpoint::Checkpointing>,
    matters: Matters,
) -> Result<Calibration> {
    let start = std::time::Instant::now();
    let jitter_before = problem.likelihood.jitter_events();
    let failures_before = problem.simulator.failures();
    guard::check(problem, seed)?;
    let label = format!(
        "{} kernel={} obs={}",
        problem.analysis.name,
        DiscrepancyKernel::label(problem.likelihood.kernel),
        problem.observables().join("+")
    );
    let sampled = match problem.sampler {
        SamplerKind::Smc => run_smc_until_converged(problem, seed, observer, checkpoint, &label, matters)?,
        SamplerKind::Ensemble => run_ensemble(problem, seed, observer, checkpoint, &label)?,
    };
    let wall = start.elapsed().as_secs_f64();
    let jitter = problem.likelihood.jitter_events() - jitter_before;
    let mut summary = summary::summarize(
        problem,
        &sampled.chains,
        sampled.evidence,
        sampled.details,
        sampled.evaluations,
        wall,
        jitter,
        seed,
    );
    summary.diagnostics.note_model_failures(problem.simulator.failures() - failures_before);
    summary.diagnostics.note_adaptation(sampled.adaptation);
    let predictions = summary::predictions(problem, &sampled.chains, seed)?;
    Ok(Calibration { chains: sampled.chains, summary, predictions })
}

/// SMC with the configured settings, sampled again with more where it did
/// not converge (`adapt`).
fn run_smc_until_converged(
    problem: &Problem,
    seed: u64,
    observer: &dyn Observer,
    checkpoint: Option<&checkpoint::Checkpointing>,
    label: &str,
    matters: Matters,
) -> Result<Sampled> {
    let mut settings = problem.analysis.sampler.smc.clone();
    let mut sampled = run_smc(problem, &settings, seed, observer, checkpoint, label)?;
    let (first, mut spent) = (sampled.evaluations, sampled.evaluations);
    let mut attempts = Vec::new();
    for rerun in 1..=adapt::MAX_RERUNS + 1 {
        let c = adapt::Convergence::of(&sampled.chains);
        attempts.push(adapt::Attempt::new(&settings, &c, sampled.evaluations));
        if c.converged() || rerun > adapt::MAX_RERUNS || !problem.analysis.sampler.adapt {
            break;
        }
        let (next, growth) = adapt::escalate(&settings, &c);
        let said = format!("{label}: not converged (largest R̂ {:.3}, smallest ESS {:.0})", c.max_rhat, c.min_ess);
        if let Some((z, e)) = sampled.evidence.filter(|(z, e)| !matters(*z, *e)) {
            crate::base::messages::note!(
                "  {said}; not sampled again: the decision weighs its log evidence {z:.1} ± {e:.1} as it is"
            );
            break;
        }
        if !adapt::affordable(first, spent, sampled.evaluations, growth) {
            crate::base::messages::note!("  {said}; another run would exceed {} times the first's cost", adapt::BUDGET);
            break;
        }
        crate::base::messages::note!(
            "  {said}; sampling again with {} particles per replicate, {} final sweeps per dimension and {} final mixture proposals",
            next.particles,
            next.final_steps_per_dim,
            next.final_mixture_proposals
        );
        settings = next;
        let ck = checkpoint.map(|c| adapt::rerun_checkpoint(c, rerun));
        sampled = run_smc(problem, &settings, seed, observer, ck.as_ref(), label)?;
        spent += sampled.evaluations;
    }
    sampled.evaluations = spent;
    if attempts.len() > 1 {
        sampled.adaptation = attempts;
    }
    Ok(sampled)
}

fn run_smc(
    problem: &Problem,
    settings: &smc::SmcSettings,
    seed: u64,
    observer: &dyn Observer,
    checkpoint: Option<&checkpoint::Checkpointing>,
    label: &str,
) -> Result<Sampled> {
    let settings = settings.clone();
    observer.begin(&format!("SMC {label}"), 1000 * settings.replicates as u64);
    let out = smc::Smc::new(settings).run_checkpointed(&problem.prior, &problem.likelihood, seed, observer, checkpoint);
    observer.end();
    let out = out?;
    let evaluations = out.likelihood_evaluations();
    let details = summary::SamplerDetails::from_smc(&out);
    let evidence = Some((out.log_evidence, out.log_evidence_err));
    Ok(Sampled { evidence, chains: out.chains, details, evaluations, adaptation: Vec::new() })
}

fn run_ensemble(
    problem: &Problem,
    seed: u64,
    observer: &dyn Observer,
    checkpoint: Option<&checkpoint::Checkpointing>,
    label: &str,
) -> Result<Sampled> {
    let settings = problem.analysis.sampler.ensemble.clone();
    observer.begin(&format!("ensemble {label}"), (settings.burn + settings.steps) as u64);
    let out = ensemble::Ensemble::new(settings).run_checkpointed(
        &problem.prior,
        &problem.likelihood,
        seed,
        observer,
        checkpoint,
    );
    observer.end();
    let out = out?;
    let details = summary::SamplerDetails::Ensemble { walkers: out.chains.chains.len(), acceptance: out.acceptance };
    let evaluations = out.likelihood_evaluations;
    Ok(Sampled { chains: out.chains, evidence: None, details, evaluations, adaptation: Vec::new() })
}

/// Writes `posterior.parquet`, `summary.json`, `predictions.parquet` and
/// `posterior_predictive.parquet` into `dir`.
pub fn write_outputs(dir: &Path, problem: &Problem, cal: &Calibration) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let prov = &cal.summary.provenance;
    let mut cols: Vec<(String, Vec<f64>)> =
        (0..cal.chains.dim).map(|p| (cal.chains.names[p].clone(), cal.chains.param(p))).collect();
    // Which chain each draw came from, so diagnostics can be recomputed.
    let chain_ids: Vec<f64> = cal
        .chains
        .chains
        .iter()
        .enumerate()
        .flat_map(|(k, c)| std::iter::repeat_n(k as f64, c.len() / cal.chains.dim))
        .collect();
    cols.push(("chain".into(), chain_ids));
    cols.extend(summary::log_density_columns(problem, &cal.chains));
    let mut df = artifacts::f64_frame(cols)?;
    // All four or none: a full disk must not leave a new posterior beside an old summary.
    let mut staged = artifacts::StagedWrites::new();
    staged.parquet(&dir.join("posterior.parquet"), &mut df, Some(prov))?;
    staged.json(&dir.join("summary.json"), &cal.summary)?;
    staged.text(&dir.join(stored::KEY_FILE), &stored::problem_key(problem))?;
    let mut pred = summary::predictions_frame(&cal.predictions)?;
    staged.parquet(&dir.join("predictions.parquet"), &mut pred, Some(prov))?;
    let mut replicates = summary::replicates_frame(problem, &cal.chains, prov.seed)?;
    staged.parquet(&dir.join("posterior_predictive.parquet"), &mut replicates, Some(prov))?;
    // The measurements fitted, so that reports and re-analyses need nothing else.
    let used: Vec<Measurement> =
        problem.measurements.iter().filter(|m| problem.observables().contains(&m.observable)).cloned().collect();
    artifacts::stage_measurements(&mut staged, &dir.join("measurements.parquet"), &used, Some(prov))?;
    staged.commit()
}
