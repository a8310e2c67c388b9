//! Adaptive tempered sequential Monte Carlo (Del Moral, Doucet & Jasra 2006;
//! Jasra et al. 2011), with random-walk Metropolis rejuvenation preconditioned
//! by the particle covariance.
//!
//! Each run tempers `π(θ) L(θ)^β` from β = 0 (prior) to β = 1 (posterior),
//! choosing every step so that the importance weights keep an effective
//! sample size of `ess_fraction × particles`. It returns equally weighted
//! posterior draws and the log-evidence. The evidence's standard error comes
//! from the genealogy-based variance estimator of Lee & Whiteley (2018), which
//! needs multinomial resampling at every step, as done here.
//!
//! Several independent replicates run in parallel; they act as the "chains" of
//! the R̂/ESS diagnostics, with each replicate's draws ordered by ancestor so
//! that copies of one particle that the moves failed to separate lower the ESS.

use super::prior::UniformPrior;
use super::{Chains, LogLikelihood};
use crate::gp::CholeskyWorkspace;
use indicatif::ProgressBar;
use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;
use rand_xoshiro::Xoshiro256PlusPlus;
use rayon::prelude::*;

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
    /// Steps after the final resampling, per dimension, to separate copies.
    pub final_steps_per_dim: f64,
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
#[derive(Clone, Debug, serde::Serialize)]
pub struct SmcStep {
    pub beta: f64,
    pub mcmc_steps: usize,
    pub acceptance: f64,
}

#[derive(Clone, Debug)]
pub struct ReplicateOutput {
    /// Final particles, row-major `particles × dim`, ordered by ancestor.
    pub particles: Vec<f64>,
    pub log_evidence: f64,
    /// Lee–Whiteley estimate of Var(Ẑ)/Z².
    pub relative_variance: f64,
    pub steps: Vec<SmcStep>,
    pub likelihood_evaluations: u64,
    /// Fraction of distinct particles after the final resampling.
    pub unique_fraction: f64,
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
}

pub struct Smc {
    pub settings: SmcSettings,
}

impl Smc {
    pub fn new(settings: SmcSettings) -> Self {
        Smc { settings }
    }

    pub fn run(&self, prior: &UniformPrior, likelihood: &dyn LogLikelihood, seed: u64, progress: Option<&ProgressBar>) -> SmcOutput {
        let k = self.settings.replicates.max(1);
        let replicates: Vec<ReplicateOutput> = (0..k)
            .into_par_iter()
            .map(|r| {
                let rseed = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15).wrapping_add(r as u64 * 0xD1B5_4A32_D192_ED03 + 1);
                run_replicate(&self.settings, prior, likelihood, rseed, progress)
            })
            .collect();
        // Pooled estimate Ẑ = mean_k Ẑ_k; its relative variance is Σ_k v_k / K²
        // (replicates are independent and each Ẑ_k ≈ Z).
        let logs: Vec<f64> = replicates.iter().map(|r| r.log_evidence).collect();
        let log_evidence = log_sum_exp(&logs) - (k as f64).ln();
        let rel_var: f64 = replicates.iter().map(|r| r.relative_variance.max(0.0)).sum::<f64>() / (k * k) as f64;
        let log_evidence_err = rel_var.ln_1p().sqrt();
        let chains = Chains { names: prior.names.clone(), dim: prior.dim(), chains: replicates.iter().map(|r| r.particles.clone()).collect() };
        SmcOutput { chains, log_evidence, log_evidence_err, replicates }
    }
}

pub fn log_sum_exp(v: &[f64]) -> f64 {
    let m = v.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    if !m.is_finite() {
        return m;
    }
    m + v.iter().map(|x| (x - m).exp()).sum::<f64>().ln()
}

/// ESS of weights `exp(delta * loglik)`, relative to nothing (absolute count).
fn weight_ess(loglik: &[f64], max_ll: f64, delta: f64) -> f64 {
    let (mut s, mut s2) = (0.0, 0.0);
    for &l in loglik {
        let w = (delta * (l - max_ll)).exp();
        s += w;
        s2 += w * w;
    }
    if s2 == 0.0 {
        0.0
    } else {
        s * s / s2
    }
}

/// Largest increment Δ ≤ 1 - β whose weights keep ESS ≥ target.
fn next_increment(loglik: &[f64], beta: f64, target_ess: f64) -> f64 {
    let max_ll = loglik.iter().cloned().filter(|l| l.is_finite()).fold(f64::NEG_INFINITY, f64::max);
    let remaining = 1.0 - beta;
    if weight_ess(loglik, max_ll, remaining) >= target_ess {
        return remaining;
    }
    let (mut lo, mut hi) = (0.0, remaining);
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if weight_ess(loglik, max_ll, mid) >= target_ess {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    // Guarantee progress even when a single particle dominates.
    lo.max(1e-12 * remaining).min(remaining)
}

/// Multinomial resampling via sorted uniforms: ancestors come out sorted, so
/// copies of one particle are adjacent.
fn multinomial_ancestors<R: Rng>(weights: &[f64], rng: &mut R) -> Vec<usize> {
    let n = weights.len();
    // Sorted uniforms from normalized cumulative exponential spacings.
    let mut cum = Vec::with_capacity(n + 1);
    let mut acc = 0.0;
    for _ in 0..=n {
        let u: f64 = rng.random();
        acc += -(1.0 - u).ln();
        cum.push(acc);
    }
    let total = cum[n];
    let mut out = Vec::with_capacity(n);
    let mut j = 0;
    let mut cw = weights[0];
    for &c in cum.iter().take(n) {
        let u = c / total;
        while u > cw && j + 1 < n {
            j += 1;
            cw += weights[j];
        }
        out.push(j);
    }
    out
}

fn reindex(x: &[f64], dim: usize, ancestors: &[usize]) -> Vec<f64> {
    let mut out = Vec::with_capacity(x.len());
    for &a in ancestors {
        out.extend_from_slice(&x[a * dim..(a + 1) * dim]);
    }
    out
}

/// Lower Cholesky factor of the particles' covariance (in the unbounded space).
fn proposal_factor(x: &[f64], dim: usize) -> Vec<f64> {
    let n = x.len() / dim;
    let mut mean = vec![0.0; dim];
    for row in x.chunks(dim) {
        for k in 0..dim {
            mean[k] += row[k] / n as f64;
        }
    }
    let mut ws = CholeskyWorkspace::new(dim);
    ws.factor.iter_mut().for_each(|v| *v = 0.0);
    for row in x.chunks(dim) {
        for j in 0..dim {
            let dj = row[j] - mean[j];
            for i in j..dim {
                ws.factor[i + j * dim] += (row[i] - mean[i]) * dj / (n as f64 - 1.0).max(1.0);
            }
        }
    }
    // A small floor keeps a collapsed cloud movable (u is O(1) under the prior).
    for k in 0..dim {
        ws.factor[k + k * dim] += 1e-18;
    }
    if ws.factorize().is_err() {
        let mut diag = vec![0.0; dim * dim];
        for k in 0..dim {
            diag[k + k * dim] = 0.1;
        }
        return diag;
    }
    for j in 0..dim {
        for i in 0..j {
            ws.factor[i + j * dim] = 0.0;
        }
    }
    ws.factor
}

/// Random-walk Metropolis moves of every particle at inverse temperature β,
/// in the unbounded coordinates u (target `L(x(u))^β π_u(u)`).
/// Returns the acceptance rate and the number of likelihood evaluations.
#[allow(clippy::too_many_arguments)]
fn rwm_moves(
    x: &mut [f64],
    loglik: &mut [f64],
    logprior: &mut [f64],
    rngs: &mut [Xoshiro256PlusPlus],
    dim: usize,
    factor: &[f64],
    scale: f64,
    beta: f64,
    steps: usize,
    prior: &UniformPrior,
    likelihood: &dyn LogLikelihood,
) -> (f64, u64) {
    let (accepted, evals) = x
        .par_chunks_mut(dim)
        .zip(loglik.par_iter_mut())
        .zip(logprior.par_iter_mut())
        .zip(rngs.par_iter_mut())
        .map(|(((xi, li), pi), rng)| {
            let mut z = vec![0.0; dim];
            let mut prop = vec![0.0; dim];
            let mut prop_x = vec![0.0; dim];
            let (mut acc, mut evals) = (0u64, 0u64);
            for _ in 0..steps {
                for zk in z.iter_mut() {
                    *zk = rng.sample(StandardNormal);
                }
                for i in 0..dim {
                    let mut s = 0.0;
                    for j in 0..=i {
                        s += factor[i + j * dim] * z[j];
                    }
                    prop[i] = xi[i] + scale * s;
                }
                let lpi = prior.from_unbounded_with_log_density(&prop, &mut prop_x);
                // Far out in u the logistic rounds onto a bound: outside the open box.
                if !prior.contains(&prop_x) {
                    continue;
                }
                let lp = likelihood.log_likelihood(&prop_x);
                evals += 1;
                let log_ratio = if li.is_finite() { beta * (lp - *li) + lpi - *pi } else if lp.is_finite() { f64::INFINITY } else { f64::NEG_INFINITY };
                let u: f64 = rng.random();
                if u.ln() < log_ratio {
                    xi.copy_from_slice(&prop);
                    *li = lp;
                    *pi = lpi;
                    acc += 1;
                }
            }
            (acc, evals)
        })
        .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    (accepted as f64 / (x.len() / dim * steps).max(1) as f64, evals)
}

fn run_replicate(settings: &SmcSettings, prior: &UniformPrior, likelihood: &dyn LogLikelihood, seed: u64, progress: Option<&ProgressBar>) -> ReplicateOutput {
    let dim = prior.dim();
    let n = settings.particles.max(2);
    let mut master = Xoshiro256PlusPlus::seed_from_u64(seed);
    // One independent stream per particle slot, so parallel moves are reproducible.
    let mut rngs: Vec<Xoshiro256PlusPlus> = (0..n)
        .map(|_| {
            master.jump();
            master.clone()
        })
        .collect();
    master.long_jump();

    // Particles live in the unbounded coordinates u; see UniformPrior::to_unbounded.
    let mut x = vec![0.0; n * dim];
    let mut loglik: Vec<f64> = x
        .par_chunks_mut(dim)
        .zip(rngs.par_iter_mut())
        .map(|(row, rng)| {
            let mut draw = vec![0.0; dim];
            prior.sample(rng, &mut draw);
            prior.to_unbounded(&draw, row);
            likelihood.log_likelihood(&draw)
        })
        .collect();
    let mut logprior: Vec<f64> = x.chunks(dim).map(|u| prior.log_density_unbounded(u)).collect();
    let mut evaluations = n as u64;
    let mut eve: Vec<usize> = (0..n).collect();

    let mut beta = 0.0;
    let mut log_z = 0.0;
    let mut stages = 0usize;
    let mut scale = 2.38 / (dim as f64).sqrt();
    let mut last_acceptance = settings.target_acceptance;
    let mut steps_log = Vec::new();
    let base_steps = (settings.steps_per_dim * dim as f64).ceil().max(1.0);
    let max_steps = (settings.max_steps_per_dim * dim as f64).ceil().max(base_steps) as usize;
    let target_ess = settings.ess_fraction * n as f64;
    let mut progress_done = 0u64;

    let weights = loop {
        let delta = next_increment(&loglik, beta, target_ess);
        let next = if 1.0 - (beta + delta) < 1e-12 { 1.0 } else { beta + delta };
        let logw: Vec<f64> = loglik.iter().map(|&l| if l.is_finite() { (next - beta) * l } else { f64::NEG_INFINITY }).collect();
        let lse = log_sum_exp(&logw);
        log_z += lse - (n as f64).ln();
        stages += 1;
        let w: Vec<f64> = logw.iter().map(|l| (l - lse).exp()).collect();
        if let Some(pb) = progress {
            let now = (next * 1000.0) as u64;
            pb.inc(now.saturating_sub(progress_done));
            progress_done = now;
        }
        if next >= 1.0 {
            break w;
        }
        let ancestors = multinomial_ancestors(&w, &mut master);
        x = reindex(&x, dim, &ancestors);
        loglik = ancestors.iter().map(|&a| loglik[a]).collect();
        logprior = ancestors.iter().map(|&a| logprior[a]).collect();
        eve = ancestors.iter().map(|&a| eve[a]).collect();

        let factor = proposal_factor(&x, dim);
        let steps = ((base_steps * (settings.target_acceptance / last_acceptance.max(1e-3)).max(1.0)).ceil() as usize).min(max_steps);
        let (acc, evals) = rwm_moves(&mut x, &mut loglik, &mut logprior, &mut rngs, dim, &factor, scale, next, steps, prior, likelihood);
        evaluations += evals;
        last_acceptance = acc;
        scale *= (2.0 * (acc - settings.target_acceptance)).exp();
        steps_log.push(SmcStep { beta: next, mcmc_steps: steps, acceptance: acc });
        beta = next;
    };

    // Lee & Whiteley (2018): Var(Ẑ)/Z² ≈ 1 - (n/(n-1))^T Σ_{i,j: E_i≠E_j} W_i W_j.
    let mut eve_mass = vec![0.0; n];
    for (e, w) in eve.iter().zip(&weights) {
        eve_mass[*e] += w;
    }
    let same_eve: f64 = eve_mass.iter().map(|s| s * s).sum();
    let nf = n as f64;
    let relative_variance = 1.0 - (nf / (nf - 1.0)).powi(stages as i32) * (1.0 - same_eve);

    // Equal-weight posterior draws, then moves to separate the copies.
    let ancestors = multinomial_ancestors(&weights, &mut master);
    let mut unique = ancestors.clone();
    unique.dedup();
    let unique_fraction = unique.len() as f64 / nf;
    x = reindex(&x, dim, &ancestors);
    loglik = ancestors.iter().map(|&a| loglik[a]).collect();
    logprior = ancestors.iter().map(|&a| logprior[a]).collect();
    let factor = proposal_factor(&x, dim);
    let final_steps = (settings.final_steps_per_dim * dim as f64).ceil() as usize;
    let (acc, evals) = rwm_moves(&mut x, &mut loglik, &mut logprior, &mut rngs, dim, &factor, scale, 1.0, final_steps, prior, likelihood);
    evaluations += evals;
    steps_log.push(SmcStep { beta: 1.0, mcmc_steps: final_steps, acceptance: acc });
    let mut particles = vec![0.0; x.len()];
    for (u, out) in x.chunks(dim).zip(particles.chunks_mut(dim)) {
        prior.from_unbounded(u, out);
    }
    let x = particles;

    ReplicateOutput { particles: x, log_evidence: log_z, relative_variance, steps: steps_log, likelihood_evaluations: evaluations, unique_fraction }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn multinomial_ancestors_are_sorted_and_follow_weights() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(5);
        let w = [0.1, 0.0, 0.6, 0.3];
        let mut counts = [0usize; 4];
        let reps = 2000;
        for _ in 0..reps {
            let a = multinomial_ancestors(&w, &mut rng);
            assert!(a.windows(2).all(|p| p[0] <= p[1]));
            for i in a {
                counts[i] += 1;
            }
        }
        let total = (reps * 4) as f64;
        for k in 0..4 {
            let p = counts[k] as f64 / total;
            // Binomial standard error of p over 8000 draws is below 0.006; allow 4σ.
            assert!((p - w[k]).abs() < 0.024, "k={k}: {p} vs {}", w[k]);
        }
        assert_eq!(counts[1], 0);
    }
}
