//! Affine-invariant ensemble MCMC with Goodman & Weare (2010) stretch moves,
//! updated in two halves as in emcee (Foreman-Mackey et al. 2013) so that
//! each half's walkers move in parallel.

use super::prior::UniformPrior;
use super::{Chains, LogLikelihood};
use crate::base::progress::Observer;
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

#[derive(Clone, Debug)]
pub struct EnsembleOutput {
    /// One chain per walker.
    pub chains: Chains,
    pub acceptance: f64,
    pub likelihood_evaluations: u64,
}

pub struct Ensemble {
    pub settings: EnsembleSettings,
}

struct Walker {
    x: Vec<f64>,
    prop: Vec<f64>,
    log_post: f64,
    rng: Xoshiro256PlusPlus,
    accepted: u64,
    trace: Vec<f64>,
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
        let dim = prior.dim();
        let mut n_walkers = if self.settings.walkers == 0 { (4 * dim).max(32) } else { self.settings.walkers.max(4) };
        n_walkers += n_walkers % 2;
        let a = self.settings.stretch;
        let mut master = Xoshiro256PlusPlus::seed_from_u64(seed);
        // Walkers move in the parameters themselves: the stretch move is affine
        // invariant there, and the logit map's heavy tails leave walkers stranded.
        let log_post = |x: &[f64]| {
            let lp = prior.log_density(x);
            if lp.is_finite() {
                lp + likelihood.log_likelihood(x)
            } else {
                f64::NEG_INFINITY
            }
        };
        let mut walkers: Vec<Walker> = (0..n_walkers)
            .map(|_| {
                master.jump();
                let mut rng = master.clone();
                let mut x = vec![0.0; dim];
                prior.sample(&mut rng, &mut x);
                Walker {
                    x,
                    prop: vec![0.0; dim],
                    log_post: f64::NEG_INFINITY,
                    rng,
                    accepted: 0,
                    trace: Vec::with_capacity(self.settings.steps / self.settings.thin.max(1) * dim + dim),
                }
            })
            .collect();
        walkers.par_iter_mut().for_each(|w| w.log_post = log_post(&w.x));
        let mut evaluations = n_walkers as u64;
        let half = n_walkers / 2;
        let total_steps = self.settings.burn + self.settings.steps;
        for step in 0..total_steps {
            for side in 0..2 {
                let (first, second) = walkers.split_at_mut(half);
                let (active, others) = if side == 0 { (first, &*second) } else { (second, &*first) };
                evaluations += active
                    .par_iter_mut()
                    .map(|w| {
                        let j = w.rng.random_range(0..others.len());
                        let u: f64 = w.rng.random();
                        // z ~ g(z) ∝ 1/sqrt(z) on [1/a, a].
                        let z = ((a - 1.0) * u + 1.0).powi(2) / a;
                        let partner = &others[j].x;
                        for k in 0..dim {
                            w.prop[k] = partner[k] + z * (w.x[k] - partner[k]);
                        }
                        let lp = log_post(&w.prop);
                        let log_ratio = (dim as f64 - 1.0) * z.ln() + lp - w.log_post;
                        let r: f64 = w.rng.random();
                        if lp.is_finite() && (r.ln() < log_ratio || !w.log_post.is_finite()) {
                            std::mem::swap(&mut w.x, &mut w.prop);
                            w.log_post = lp;
                            if step >= self.settings.burn {
                                w.accepted += 1;
                            }
                        }
                        1u64
                    })
                    .sum::<u64>();
            }
            if step >= self.settings.burn && (step - self.settings.burn).is_multiple_of(self.settings.thin.max(1)) {
                for w in walkers.iter_mut() {
                    w.trace.extend_from_slice(&w.x);
                }
            }
            observer.advance(1);
        }
        let acceptance =
            walkers.iter().map(|w| w.accepted).sum::<u64>() as f64 / (n_walkers * self.settings.steps.max(1)) as f64;
        let chains = Chains { names: prior.names.clone(), dim, chains: walkers.into_iter().map(|w| w.trace).collect() };
        EnsembleOutput { chains, acceptance, likelihood_evaluations: evaluations }
    }
}
