//! Affine-invariant ensemble MCMC with Goodman & Weare (2010) stretch moves,
//! updated in two halves as in emcee (Foreman-Mackey et al. 2013) so that
//! each half's walkers move in parallel.

use super::algorithm::{drive, SamplerError, SamplingAlgorithm, Stopped};
use super::chains::Chains;
use super::checkpoint::{f64_bit, f64_bits, Checkpointing};
use super::target::LogLikelihood;
use crate::base::progress::Observer;
use crate::engine::calibrate::sampler::uniform_prior::UniformPrior;
use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use rayon::prelude::*;

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EnsembleSettings {
    /// Number of walkers; 0 means max(32, 4 × dim), rounded up to even.
    pub walkers: usize,
    /// Steps kept after burn-in.
    pub steps: usize,
    /// Steps discarded at the start.
    pub burn: usize,
    /// Keep every `thin`-th step (memory only: thinning never adds information).
    pub thin: usize,
    /// Stretch-move scale a (emcee's default is 2).
    pub stretch: f64,
}

impl Default for EnsembleSettings {
    fn default() -> Self {
        EnsembleSettings { walkers: 0, steps: 40000, burn: 10000, thin: 10, stretch: 2.0 }
    }
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct EnsembleOutput {
    /// One chain per walker.
    pub chains: Chains,
    #[serde(with = "f64_bit")]
    pub acceptance: f64,
    pub likelihood_evaluations: u64,
}

pub struct Ensemble {
    pub settings: EnsembleSettings,
}

/// One walker: where it is, its stream, what it has kept.
#[derive(Clone, serde::Serialize, serde::Deserialize)]
struct Walker {
    #[serde(with = "f64_bits")]
    x: Vec<f64>,
    /// Scratch for the proposal (not state).
    #[serde(skip)]
    prop: Vec<f64>,
    #[serde(with = "f64_bit")]
    log_post: f64,
    rng: Xoshiro256PlusPlus,
    accepted: u64,
    #[serde(with = "f64_bits")]
    trace: Vec<f64>,
}

/// The ensemble between steps: everything a checkpoint must store.
#[derive(serde::Serialize, serde::Deserialize)]
pub struct EnsembleState {
    walkers: Vec<Walker>,
    step: usize,
    evaluations: u64,
}

/// What fixes the target while the walkers move.
struct Stretch<'a> {
    settings: &'a EnsembleSettings,
    prior: &'a UniformPrior,
    likelihood: &'a dyn LogLikelihood,
    dim: usize,
}

impl Stretch<'_> {
    /// Walkers move in the parameters themselves: the stretch move is affine
    /// invariant there, and the logit map's heavy tails leave walkers stranded.
    fn log_post(&self, x: &[f64]) -> f64 {
        let lp = self.prior.log_density(x);
        if lp.is_finite() {
            lp + self.likelihood.log_likelihood(x)
        } else {
            f64::NEG_INFINITY
        }
    }

    fn total_steps(&self) -> usize {
        self.settings.burn + self.settings.steps
    }

    /// One half of the walkers stretched towards or away from partners in the other half.
    fn move_half(&self, active: &mut [Walker], others: &[Walker], keep: bool) -> u64 {
        let (a, dim) = (self.settings.stretch, self.dim);
        active
            .par_iter_mut()
            .map(|w| {
                w.prop.resize(dim, 0.0);
                let j = w.rng.random_range(0..others.len());
                let u: f64 = w.rng.random();
                // z ~ g(z) ∝ 1/sqrt(z) on [1/a, a].
                let z = ((a - 1.0) * u + 1.0).powi(2) / a;
                let partner = &others[j].x;
                for k in 0..dim {
                    w.prop[k] = partner[k] + z * (w.x[k] - partner[k]);
                }
                let lp = self.log_post(&w.prop);
                let log_ratio = (dim as f64 - 1.0) * z.ln() + lp - w.log_post;
                let r: f64 = w.rng.random();
                if lp.is_finite() && (r.ln() < log_ratio || !w.log_post.is_finite()) {
                    std::mem::swap(&mut w.x, &mut w.prop);
                    w.log_post = lp;
                    if keep {
                        w.accepted += 1;
                    }
                }
                1u64
            })
            .sum()
    }
}

impl SamplingAlgorithm for Stretch<'_> {
    type State = EnsembleState;
    type Output = EnsembleOutput;

    fn init(&self, seed: u64) -> EnsembleState {
        let mut n_walkers =
            if self.settings.walkers == 0 { (4 * self.dim).max(32) } else { self.settings.walkers.max(4) };
        n_walkers += n_walkers % 2;
        let mut master = Xoshiro256PlusPlus::seed_from_u64(seed);
        let mut walkers: Vec<Walker> = (0..n_walkers)
            .map(|_| {
                master.jump();
                let mut rng = master.clone();
                let mut x = vec![0.0; self.dim];
                self.prior.sample(&mut rng, &mut x);
                let kept = self.settings.steps / self.settings.thin.max(1) * self.dim + self.dim;
                Walker {
                    x,
                    prop: vec![0.0; self.dim],
                    log_post: f64::NEG_INFINITY,
                    rng,
                    accepted: 0,
                    trace: Vec::with_capacity(kept),
                }
            })
            .collect();
        walkers.par_iter_mut().for_each(|w| w.log_post = self.log_post(&w.x));
        EnsembleState { walkers, step: 0, evaluations: n_walkers as u64 }
    }

    fn step(&self, st: &mut EnsembleState, observer: &dyn Observer) -> Result<bool, SamplerError> {
        if st.step >= self.total_steps() {
            return Ok(true);
        }
        let keep = st.step >= self.settings.burn;
        let half = st.walkers.len() / 2;
        for side in 0..2 {
            let (first, second) = st.walkers.split_at_mut(half);
            let (active, others) = if side == 0 { (first, &*second) } else { (second, &*first) };
            st.evaluations += self.move_half(active, others, keep);
        }
        if keep && (st.step - self.settings.burn).is_multiple_of(self.settings.thin.max(1)) {
            for w in st.walkers.iter_mut() {
                w.trace.extend_from_slice(&w.x);
            }
        }
        st.step += 1;
        observer.advance(1);
        Ok(st.step >= self.total_steps())
    }

    fn finish(&self, st: EnsembleState) -> EnsembleOutput {
        let n = st.walkers.len();
        let acceptance =
            st.walkers.iter().map(|w| w.accepted).sum::<u64>() as f64 / (n * self.settings.steps.max(1)) as f64;
        let chains = Chains::new(self.prior.names.clone(), self.dim, st.walkers.into_iter().map(|w| w.trace).collect());
        EnsembleOutput { chains, acceptance, likelihood_evaluations: st.evaluations }
    }

    fn progress_units(&self) -> u64 {
        self.total_steps() as u64
    }
}

impl Ensemble {
    pub fn new(settings: EnsembleSettings) -> Self {
        Ensemble { settings }
    }

    pub fn run(
        &self,
        prior: &UniformPrior,
        likelihood: &dyn LogLikelihood,
        seed: u64,
        observer: &dyn Observer,
    ) -> EnsembleOutput {
        match self.run_checkpointed(prior, likelihood, seed, observer, None) {
            Ok(out) => out,
            Err(e) => unreachable!("an ensemble without a checkpoint never stops early: {e}"),
        }
    }

    /// As `run`, saving the ensemble's state as it goes (`ensemble` in the
    /// checkpoint folder) and resuming from an interrupted run's.
    pub fn run_checkpointed(
        &self,
        prior: &UniformPrior,
        likelihood: &dyn LogLikelihood,
        seed: u64,
        observer: &dyn Observer,
        ck: Option<&Checkpointing>,
    ) -> Result<EnsembleOutput, Stopped> {
        let algorithm = Stretch { settings: &self.settings, prior, likelihood, dim: prior.dim() };
        let started = std::time::Instant::now();
        drive(&algorithm, seed, observer, ck.map(|c| (c, "ensemble"))).into_result(ck, started, "")
    }
}
