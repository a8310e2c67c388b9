//! Adaptive tempered sequential Monte Carlo (Del Moral, Doucet & Jasra 2006;
//! Jasra et al. 2011), with random-walk Metropolis rejuvenation preconditioned
//! by the particle covariance and independent Metropolis–Hastings proposals
//! from a Gaussian mixture fitted to the cloud (`mixture`), which cross thin
//! curved ridges that the random walk only crawls along.
//!
//! Each run tempers `π(θ) L(θ)^β` from β = 0 (prior) to β = 1 (posterior),
//! choosing every step so that the importance weights keep an effective
//! sample size of `ess_fraction × particles`. It returns equally weighted
//! posterior draws and the log-evidence. The evidence's standard error comes
//! from the genealogy-based variance estimator of Lee & Whiteley (2018), which
//! needs multinomial resampling at every step, as done here; replicates
//! whose log-evidences scatter beyond those errors (stuck in different
//! modes) give the error of their scatter instead (`pooled`).
//!
//! When the likelihood is a sum of independent terms (one per observable, each
//! with its own discrepancy hyperparameters), each sweep also moves the shared
//! parameters alone and each term's own parameters alone, the latter at the
//! cost of one term (Metropolis within Gibbs). When the terms are linked (a
//! joint likelihood), a term's move is first screened by that term's marginal
//! and pays for a whole evaluation only if it passes (delayed acceptance).
//!
//! Several independent replicates run in parallel; they act as the "chains" of
//! the R̂/ESS diagnostics, with each replicate's draws ordered by ancestor so
//! that copies of one particle that the moves failed to separate lower the ESS.

use super::algorithm::{drive, End, SamplerError, SamplingAlgorithm, Stopped};
use super::chains::Chains;
use super::checkpoint::{f64_bit, f64_bits, Checkpointing};
use super::target::{LogLikelihood, SeparableTerms, TermStatistics, TermStructure};
use crate::base::progress::Observer;
use crate::engine::calibrate::sampler::uniform_prior::UniformPrior;
use crate::engine::gp::CholeskyWorkspace;
use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;
use rand_xoshiro::Xoshiro256PlusPlus;
use rayon::prelude::*;

mod copies;
mod mixture;
mod moves;
mod pooled;
mod reach;
mod tempering;

use mixture::Mixture;
use moves::*;
pub use reach::Abandon;
pub use tempering::log_sum_exp;
use tempering::*;

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SmcSettings {
    /// Particles per replicate.
    pub particles: usize,
    /// Independent replicates (run in parallel; used for R̂).
    pub replicates: usize,
    /// Target ESS of the incremental weights, as a fraction of `particles`.
    pub ess_fraction: f64,
    /// Base number of Metropolis steps per tempering step, per dimension (2, as
    /// the paper's pocoMC runs; the bundled configs use the same).
    pub steps_per_dim: f64,
    /// Cap on the adaptive number of steps, per dimension.
    pub max_steps_per_dim: f64,
    /// Steps after the final resampling, per dimension, to separate copies:
    /// at most this many (a tempering step's count when the final mixture
    /// proposals have already moved 99% of the particles), stopping sooner
    /// once the copies are as good as independent (`copies`).
    pub final_steps_per_dim: f64,
    /// Independent Metropolis–Hastings proposals per particle at each
    /// tempering step, drawn from a Gaussian mixture fitted to the cloud.
    pub mixture_proposals: usize,
    /// The same after the final resampling.
    pub final_mixture_proposals: usize,
    pub target_acceptance: f64,
}

impl Default for SmcSettings {
    fn default() -> Self {
        SmcSettings {
            particles: 2000,
            replicates: 4,
            ess_fraction: 0.5,
            steps_per_dim: 2.0,
            max_steps_per_dim: 12.0,
            final_steps_per_dim: 15.0,
            mixture_proposals: 2,
            final_mixture_proposals: 10,
            target_acceptance: 0.234,
        }
    }
}

impl SmcSettings {
    /// Close to the paper's pocoMC run: 500 × ndim particles in all,
    /// 2 × ndim MCMC steps per iteration.
    pub fn paper(dim: usize) -> Self {
        let replicates = 4;
        SmcSettings { particles: (500 * dim).div_ceil(replicates), replicates, ..Default::default() }
    }
}

/// What one tempering step did.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct SmcStep {
    pub beta: f64,
    /// Sweeps: each moves every group of coordinates once.
    pub mcmc_steps: usize,
    /// Acceptance of the joint move of all coordinates (of the first group
    /// where there is none: above `JOINT_MOVE_MAX_DIM` coordinates).
    pub acceptance: f64,
    /// Acceptance per move group: joint, then (with independent likelihood
    /// terms) the shared parameters and each term's own parameters.
    pub group_acceptance: Vec<f64>,
    /// Acceptance of the independent proposals from the fitted mixture.
    #[serde(default)]
    pub mixture_acceptance: f64,
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct ReplicateOutput {
    /// Final particles, row-major `particles × dim`, ordered by ancestor.
    #[serde(with = "f64_bits")]
    pub particles: Vec<f64>,
    #[serde(with = "f64_bit")]
    pub log_evidence: f64,
    /// Lee–Whiteley estimate of Var(Ẑ)/Z².
    #[serde(with = "f64_bit")]
    pub relative_variance: f64,
    pub steps: Vec<SmcStep>,
    pub likelihood_evaluations: u64,
    /// Evaluations of a single likelihood term (one observable's block), or
    /// of a term's screen for a joint likelihood.
    pub term_evaluations: u64,
    /// Fraction of distinct particles after the final resampling.
    #[serde(with = "f64_bit")]
    pub unique_fraction: f64,
    /// The β at which the replicate stopped because its final log evidence
    /// could not reach what was asked (`Abandon`): its particles are then
    /// drawn from π_β and `log_evidence` is the upper estimate it stopped at.
    #[serde(default)]
    pub abandoned_at: Option<f64>,
}

#[derive(Clone, Debug)]
pub struct SmcOutput {
    pub chains: Chains,
    pub log_evidence: f64,
    pub log_evidence_err: f64,
    pub replicates: Vec<ReplicateOutput>,
}

impl SmcOutput {
    pub fn likelihood_evaluations(&self) -> u64 {
        self.replicates.iter().map(|r| r.likelihood_evaluations).sum()
    }

    /// The highest β at which a replicate was abandoned, if any was: the
    /// log evidence is then an upper estimate, not an estimate.
    pub fn abandoned_at(&self) -> Option<f64> {
        self.replicates.iter().filter_map(|r| r.abandoned_at).reduce(f64::max)
    }
}

pub struct Smc {
    pub settings: SmcSettings,
}

impl Smc {
    pub fn new(settings: SmcSettings) -> Self {
        Smc { settings }
    }

    /// Runs every replicate; an error when tempering cannot go on.
    pub fn run(
        &self,
        prior: &UniformPrior,
        likelihood: &dyn LogLikelihood,
        seed: u64,
        observer: &dyn Observer,
    ) -> Result<SmcOutput, Stopped> {
        self.run_checkpointed(prior, likelihood, seed, observer, None)
    }

    /// As `run`, saving each replicate's state after tempering steps and
    /// resuming from what an earlier, interrupted run of the same problem saved
    /// (`replicate_<k>` while it runs, `replicate_<k>.done` once finished).
    pub fn run_checkpointed(
        &self,
        prior: &UniformPrior,
        likelihood: &dyn LogLikelihood,
        seed: u64,
        observer: &dyn Observer,
        ck: Option<&Checkpointing>,
    ) -> Result<SmcOutput, Stopped> {
        self.run_abandoning(prior, likelihood, seed, observer, ck, None)
    }

    /// As `run_checkpointed`, each replicate stopping early once `abandon`
    /// says its final log evidence cannot reach what was asked of it.
    pub fn run_abandoning(
        &self,
        prior: &UniformPrior,
        likelihood: &dyn LogLikelihood,
        seed: u64,
        observer: &dyn Observer,
        ck: Option<&Checkpointing>,
        abandon: Option<Abandon>,
    ) -> Result<SmcOutput, Stopped> {
        let k = self.settings.replicates.max(1);
        if prior.dim() == 0 {
            return Ok(self.point_posterior(likelihood, k));
        }
        let algorithm = Tempered::new(&self.settings, prior, likelihood, abandon);
        let started = std::time::Instant::now();
        let results: Vec<End<ReplicateOutput>> = (0..k)
            .into_par_iter()
            .map(|r| {
                let rseed = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15).wrapping_add(r as u64 * 0xD1B5_4A32_D192_ED03 + 1);
                let name = format!("replicate_{r}");
                drive(&algorithm, rseed, observer, ck.map(|c| (c, name.as_str())))
            })
            .collect();
        let mut replicates = Vec::with_capacity(k);
        for (r, end) in results.into_iter().enumerate() {
            replicates.push(end.into_result(ck, started, &format!("replicate {r}: "))?);
        }
        // Pooled estimate Ẑ = mean_k Ẑ_k; its error from the replicates' own
        // and, where they disagree beyond it, from their scatter (`pooled`).
        let logs: Vec<f64> = replicates.iter().map(|r| r.log_evidence).collect();
        let variances: Vec<f64> = replicates.iter().map(|r| r.relative_variance).collect();
        let (log_evidence, log_evidence_err) = pooled::pool(&logs, &variances);
        let chains =
            Chains::new(prior.names.clone(), prior.dim(), replicates.iter().map(|r| r.particles.clone()).collect());
        Ok(SmcOutput { chains, log_evidence, log_evidence_err, replicates })
    }
}

impl Smc {
    /// A model with nothing to calibrate (every constant known, no
    /// discrepancy): the prior is one point, so the posterior is that point
    /// and the evidence its likelihood, exactly; each replicate holds
    /// `particles` empty draws so that the chains keep their shape.
    fn point_posterior(&self, likelihood: &dyn LogLikelihood, k: usize) -> SmcOutput {
        let log_l = likelihood.log_likelihood(&[]);
        let step = SmcStep {
            beta: 1.0,
            mcmc_steps: 0,
            acceptance: 0.0,
            group_acceptance: Vec::new(),
            mixture_acceptance: 0.0,
        };
        let replicate = ReplicateOutput {
            particles: Vec::new(),
            log_evidence: log_l,
            relative_variance: 0.0,
            steps: vec![step],
            likelihood_evaluations: 1,
            term_evaluations: 0,
            unique_fraction: 1.0,
            abandoned_at: None,
        };
        let chains = Chains::of_a_point(k, self.settings.particles.max(2));
        SmcOutput { chains, log_evidence: log_l, log_evidence_err: 0.0, replicates: vec![replicate; k] }
    }
}

/// The fraction of particles that must have accepted an independent proposal
/// after the final resampling for the final random-walk sweeps to be cut to
/// a tempering step's count.
const MOVED_ENOUGH: f64 = 0.99;

/// The final sweeps stop once no coordinate's correlation among the copies
/// of the final resampling exceeds this by more than its estimate's error
/// (0.06 at 2 000 particles): with about a third of the draws copies, an
/// ESS of about 90% of the particles' count or more, as far as their common
/// ancestry goes.
const SEPARATED_COPIES: f64 = 0.05;

/// Tempering steps after which a replicate that has not reached β = 1 stops
/// (typical runs take 10–60).
pub const MAX_TEMPERING_STEPS: usize = 1000;

/// One replicate's whole state between tempering steps (after BlackJAX's
/// tempered SMC state): everything a checkpoint must store to resume it.
#[derive(Clone, serde::Serialize, serde::Deserialize)]
struct ReplicateState {
    cloud: Cloud,
    /// One stream per particle slot, so parallel moves are reproducible.
    rngs: Vec<Xoshiro256PlusPlus>,
    /// Resampling's stream.
    master: Xoshiro256PlusPlus,
    /// Each particle's ancestor at β = 0 (for the Lee–Whiteley variance).
    eve: Vec<usize>,
    groups: Vec<MoveGroup>,
    #[serde(with = "f64_bit")]
    beta: f64,
    #[serde(with = "f64_bit")]
    log_z: f64,
    stages: usize,
    #[serde(with = "f64_bit")]
    last_acceptance: f64,
    steps: Vec<SmcStep>,
    evaluations: u64,
    term_evaluations: u64,
    /// The weights at β = 1, set by the step that reaches it.
    #[serde(default, with = "f64_bits")]
    final_weights: Vec<f64>,
    /// The largest log-likelihood a particle has had (`tempering::floor_at`).
    #[serde(default = "nothing_seen", with = "f64_bit")]
    best: f64,
    /// Where the replicate was abandoned (`Abandon`): β and the upper
    /// estimate of the final log evidence it stopped at.
    #[serde(default)]
    abandoned: Option<(f64, f64)>,
}

fn nothing_seen() -> f64 {
    f64::NEG_INFINITY
}

/// What stays fixed while a replicate tempers: the target and the settings
/// derived from its size. `init`, `step` and `finish` move one state.
struct Tempered<'a> {
    settings: &'a SmcSettings,
    prior: &'a UniformPrior,
    likelihood: &'a dyn LogLikelihood,
    structure: Option<TermStructure>,
    /// What each particle keeps of the likelihood's terms, and how many values.
    cache: (TermCache<'a>, usize),
    n: usize,
    dim: usize,
    base_steps: f64,
    max_steps: usize,
    final_steps: usize,
    target_ess: f64,
    abandon: Option<Abandon<'a>>,
}

impl SamplingAlgorithm for Tempered<'_> {
    type State = ReplicateState;
    type Output = ReplicateOutput;

    fn init(&self, seed: u64) -> ReplicateState {
        self.init_replicate(seed)
    }

    fn step(&self, st: &mut ReplicateState, observer: &dyn Observer) -> Result<bool, SamplerError> {
        match self.temper(st, observer)? {
            Some(weights) => {
                st.final_weights = weights;
                Ok(true)
            }
            None => Ok(false),
        }
    }

    fn finish(&self, mut st: ReplicateState) -> ReplicateOutput {
        let weights = std::mem::take(&mut st.final_weights);
        match st.abandoned {
            Some(at) => self.abandon_replicate(st, &weights, at),
            None => self.finish_replicate(st, &weights),
        }
    }

    fn progress_units(&self) -> u64 {
        1000
    }
}

impl<'a> Tempered<'a> {
    fn new(
        settings: &'a SmcSettings,
        prior: &'a UniformPrior,
        likelihood: &'a dyn LogLikelihood,
        abandon: Option<Abandon<'a>>,
    ) -> Self {
        let dim = prior.dim();
        let n = settings.particles.max(2);
        let structure = likelihood.term_structure();
        let cache = TermCache::of(structure.as_ref(), likelihood);
        // A sweep moves every group once, so its length is set by the largest group
        // that is not the joint move (or by the joint move when it is alone).
        let sweep_dim = move_groups(dim, structure.as_ref())
            .iter()
            .map(|g| g.coords.len())
            .filter(|&k| k < dim)
            .max()
            .unwrap_or(dim);
        let base_steps = (settings.steps_per_dim * sweep_dim as f64).ceil().max(1.0);
        Tempered {
            settings,
            prior,
            likelihood,
            structure,
            cache,
            n,
            dim,
            base_steps,
            max_steps: (settings.max_steps_per_dim * sweep_dim as f64).ceil().max(base_steps) as usize,
            final_steps: (settings.final_steps_per_dim * sweep_dim as f64).ceil() as usize,
            target_ess: settings.ess_fraction * n as f64,
            abandon,
        }
    }

    /// The target at the floor `floor_at(best, β)`; a target that keeps
    /// terms moves them at a term's cost without a total to compare, so it
    /// has none.
    /// The floor never passes the cloud's own best (`loglik`): should every
    /// particle have fallen that far below the best ever seen, which the
    /// moves make a chance of e^-200, none is dropped.
    fn target(&self, best: f64, beta: f64, loglik: &[f64]) -> Target<'a> {
        let floor = match self.cache.0 {
            TermCache::None => floor_at(best, beta).min(loglik.iter().copied().fold(f64::NEG_INFINITY, f64::max)),
            _ => f64::NEG_INFINITY,
        };
        Target { prior: self.prior, likelihood: self.likelihood, cache: self.cache.0, floor }
    }

    /// The particles drawn from the prior, at β = 0.
    fn init_replicate(&self, seed: u64) -> ReplicateState {
        let mut master = Xoshiro256PlusPlus::seed_from_u64(seed);
        let mut rngs: Vec<Xoshiro256PlusPlus> = (0..self.n)
            .map(|_| {
                master.jump();
                master.clone()
            })
            .collect();
        master.long_jump();
        let cloud = initial_cloud(self.prior, self.likelihood, &mut rngs, self.n, self.cache);
        ReplicateState {
            cloud,
            rngs,
            master,
            eve: (0..self.n).collect(),
            groups: move_groups(self.dim, self.structure.as_ref()),
            beta: 0.0,
            log_z: 0.0,
            stages: 0,
            last_acceptance: self.settings.target_acceptance,
            steps: Vec::new(),
            evaluations: self.n as u64,
            term_evaluations: 0,
            final_weights: Vec::new(),
            best: f64::NEG_INFINITY,
            abandoned: None,
        }
    }

    /// One tempering step: reweight to the next β, and, unless that is 1,
    /// resample and move. Returns the final weights once β reaches 1, and an
    /// error when tempering cannot go on: no particle has a finite likelihood
    /// (the weights are undefined), or β has not reached 1 in
    /// [`MAX_TEMPERING_STEPS`] steps.
    fn temper(&self, st: &mut ReplicateState, observer: &dyn Observer) -> Result<Option<Vec<f64>>, SamplerError> {
        if !st.cloud.loglik.iter().any(|l| l.is_finite()) {
            return Err(SamplerError::NoFiniteLikelihood { beta: st.beta });
        }
        if st.stages >= MAX_TEMPERING_STEPS {
            return Err(SamplerError::TemperingStalled { beta: st.beta, steps: st.stages });
        }
        let n = self.n;
        let delta = next_increment(&st.cloud.loglik, st.beta, self.target_ess);
        let next = if 1.0 - (st.beta + delta) < 1e-12 { 1.0 } else { st.beta + delta };
        st.best = st.cloud.loglik.iter().copied().filter(|l| l.is_finite()).fold(st.best, f64::max);
        let target = self.target(st.best, next, &st.cloud.loglik);
        drop_below(&mut st.cloud.loglik, target.floor);
        let logw: Vec<f64> = st
            .cloud
            .loglik
            .iter()
            .map(|&l| if l.is_finite() { (next - st.beta) * l } else { f64::NEG_INFINITY })
            .collect();
        let lse = log_sum_exp(&logw);
        st.log_z += lse - (n as f64).ln();
        st.stages += 1;
        let w: Vec<f64> = logw.iter().map(|l| (l - lse).exp()).collect();
        observer.advance(((next * 1000.0) as u64).saturating_sub((st.beta * 1000.0) as u64));
        if next >= 1.0 {
            return Ok(Some(w));
        }
        if let Some(abandon) = self.abandon {
            let reach = reach::final_log_evidence_at_most(st.log_z, next, &st.cloud.loglik, &w);
            if abandon(reach) {
                observer.advance(1000u64.saturating_sub((next * 1000.0) as u64));
                st.abandoned = Some((next, reach));
                return Ok(Some(w));
            }
        }
        let ancestors = multinomial_ancestors(&w, &mut st.master);
        st.cloud.resample(&ancestors);
        st.eve = ancestors.iter().map(|&a| st.eve[a]).collect();
        update_factors(&mut st.groups, &st.cloud.x, self.dim);
        let mixture_acceptance = self.independent_moves(st, next, self.settings.mixture_proposals, target).acceptance();
        let steps = ((self.base_steps * (self.settings.target_acceptance / st.last_acceptance.max(1e-3)).max(1.0))
            .ceil() as usize)
            .min(self.max_steps);
        let counts = mutate(&mut st.cloud, &mut st.rngs, &st.groups, next, steps, target);
        st.evaluations += counts.full_evaluations;
        st.term_evaluations += counts.term_evaluations;
        for (gi, g) in st.groups.iter_mut().enumerate() {
            g.scale *= (2.0 * (counts.acceptance(gi) - self.settings.target_acceptance)).exp();
        }
        st.last_acceptance = (0..st.groups.len()).map(|gi| counts.acceptance(gi)).fold(f64::INFINITY, f64::min);
        st.steps.push(SmcStep {
            beta: next,
            mcmc_steps: steps,
            acceptance: counts.acceptance(0),
            group_acceptance: (0..st.groups.len()).map(|gi| counts.acceptance(gi)).collect(),
            mixture_acceptance,
        });
        st.beta = next;
        Ok(None)
    }

    /// `proposals` independent moves of every particle from a mixture fitted
    /// to the cloud (none when the cloud has no spread).
    fn independent_moves(
        &self,
        st: &mut ReplicateState,
        beta: f64,
        proposals: usize,
        target: Target,
    ) -> IndependentCounts {
        if proposals == 0 {
            return IndependentCounts::default();
        }
        let Some(mixture) = Mixture::fit(&st.cloud.x, self.dim, &mut st.master) else {
            return IndependentCounts::default();
        };
        let counts = independent_moves(&mut st.cloud, &mut st.rngs, &mixture, beta, proposals, target);
        st.evaluations += counts.evaluations;
        counts
    }

    /// At β = 1: the evidence's error, then equal-weight draws, moved to
    /// separate the copies that resampling made.
    fn finish_replicate(&self, mut st: ReplicateState, weights: &[f64]) -> ReplicateOutput {
        let nf = self.n as f64;
        let relative_variance = relative_variance(&st.eve, st.stages, weights);

        let ancestors = multinomial_ancestors(weights, &mut st.master);
        let mut unique = ancestors.clone();
        unique.dedup();
        let unique_fraction = unique.len() as f64 / nf;
        st.cloud.resample(&ancestors);
        update_factors(&mut st.groups, &st.cloud.x, self.dim);
        let target = self.target(st.best, 1.0, &st.cloud.loglik);
        let independent = self.independent_moves(&mut st, 1.0, self.settings.final_mixture_proposals, target);
        // Where nearly every copy has already been replaced by an independent
        // draw, the random walk only refines locally, at a tempering step's count.
        let sweeps = if independent.moved as f64 >= MOVED_ENOUGH * nf {
            (self.base_steps as usize).min(self.final_steps)
        } else {
            self.final_steps
        };
        // Sweep by sweep (each particle's stream goes on where it stopped, so
        // the draws are those of one longer call cut short) until the copies
        // are as good as independent.
        let groups = st.groups.len();
        let mut counts = MoveCounts { accepted: vec![0; groups], proposed: vec![0; groups], ..Default::default() };
        let mut done = 0;
        while done < sweeps {
            counts = counts.merge(mutate(&mut st.cloud, &mut st.rngs, &st.groups, 1.0, 1, target));
            done += 1;
            if copies::separated(&st.cloud.x, self.dim, &ancestors, SEPARATED_COPIES) {
                break;
            }
        }
        st.steps.push(SmcStep {
            beta: 1.0,
            mcmc_steps: done,
            acceptance: counts.acceptance(0),
            group_acceptance: (0..st.groups.len()).map(|gi| counts.acceptance(gi)).collect(),
            mixture_acceptance: independent.acceptance(),
        });
        let mut particles = vec![0.0; st.cloud.x.len()];
        for (u, out) in st.cloud.x.chunks(self.dim).zip(particles.chunks_mut(self.dim)) {
            self.prior.from_unbounded(u, out);
        }
        ReplicateOutput {
            particles,
            log_evidence: st.log_z,
            relative_variance,
            steps: st.steps,
            likelihood_evaluations: st.evaluations + counts.full_evaluations,
            term_evaluations: st.term_evaluations + counts.term_evaluations,
            unique_fraction,
            abandoned_at: None,
        }
    }
}
