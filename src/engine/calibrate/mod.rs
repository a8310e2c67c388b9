//! MD-augmented Bayesian calibration, in three rooms in the order data flow:
//! `likelihood` (the data's covariance, its structure, and the forms of the
//! Kennedy–O'Hagan Gaussian), `sampler` (the interface every sampling
//! algorithm implements, SMC, the ensemble sampler, adaptation,
//! checkpoints) and `results` (summaries, convergence diagnostics,
//! predictions, stored fits).
//!
//! A sampler sees a calibration problem as a [`UniformPrior`] and a
//! [`LogLikelihood`]; [`Problem`] builds both from an [`Analysis`] (a config
//! resolved once) and data.

pub mod analysis;
pub mod guard;
pub mod likelihood;
pub mod problem;
pub mod results;
pub mod sampler;

use crate::base::artifacts::{self, Measurement};
use crate::base::progress::Observer;
use crate::engine::gp::DiscrepancyKernel;
pub use analysis::Analysis;
use anyhow::{Context, Result};
pub use likelihood::{MdLikelihood, ObservableBlock};
pub use problem::{checkpoint_key, Overrides, Problem};
pub use results::Calibration;
use results::{stored, summary};
pub use sampler::chains::Chains;
pub use sampler::settings::{SamplerConfig, SamplerKind};
pub use sampler::target::{LogLikelihood, SeparableTerms, TermStatistics, TermStructure};
pub use sampler::uniform_prior::UniformPrior;
use sampler::{adapt, checkpoint, ensemble, smc};
use std::path::Path;

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

/// How far a calibration's answer can still matter to whoever asked for
/// it: whether to sample again for convergence (`matters`), and whether to
/// stop tempering once the final log evidence cannot reach what is asked
/// (`abandon`, given an upper estimate of it; `smc::Abandon`).
#[derive(Clone, Copy)]
pub struct Judge<'a> {
    pub matters: Matters<'a>,
    pub abandon: Option<smc::Abandon<'a>>,
}

impl Judge<'_> {
    /// Every answer matters: sampled to the end, and again until converged.
    pub const ALWAYS: Judge<'static> = Judge { matters: &|_, _| true, abandon: None };
}

/// As `run`, as far as `judge` says the answer can still change a decision.
pub fn run_judged(problem: &Problem, seed: u64, observer: &dyn Observer, judge: Judge) -> Result<Calibration> {
    sample(problem, seed, observer, None, judge)
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
    sample(problem, seed, observer, checkpoint, Judge::ALWAYS)
}

fn sample(
    problem: &Problem,
    seed: u64,
    observer: &dyn Observer,
    checkpoint: Option<&checkpoint::Checkpointing>,
    judge: Judge,
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
        // Nothing to sample: SMC's one point and its exact evidence, whichever sampler was asked for.
        _ if problem.prior.dim() == 0 => run_smc_until_converged(problem, seed, observer, checkpoint, &label, judge)?,
        SamplerKind::Smc => run_smc_until_converged(problem, seed, observer, checkpoint, &label, judge)?,
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
    judge: Judge,
) -> Result<Sampled> {
    let mut settings = problem.analysis.sampler.smc.clone();
    let mut sampled = run_smc(problem, &settings, seed, observer, checkpoint, label, judge.abandon)?;
    if let Some(beta) = sampled.details.abandoned_at() {
        crate::base::messages::note!(
            "  {label}: stopped at β = {beta:.2e}, its log evidence at most {:.1}: behind any decision",
            sampled.evidence.map_or(f64::NAN, |e| e.0)
        );
        return Ok(sampled);
    }
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
        if let Some((z, e)) = sampled.evidence.filter(|(z, e)| !(judge.matters)(*z, *e)) {
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
        sampled = run_smc(problem, &settings, seed, observer, ck.as_ref(), label, None)?;
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
    abandon: Option<smc::Abandon>,
) -> Result<Sampled> {
    let settings = settings.clone();
    observer.begin(&format!("SMC {label}"), 1000 * settings.replicates as u64);
    let out = smc::Smc::new(settings).run_abandoning(
        &problem.prior,
        &problem.likelihood,
        seed,
        observer,
        checkpoint,
        abandon,
    );
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
        .flat_map(|(k, c)| std::iter::repeat_n(k as f64, cal.chains.draws_in(c)))
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
