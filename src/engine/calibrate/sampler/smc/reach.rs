//! How far a tempering replicate could still go: an upper estimate of its
//! final log evidence from the particles it has, so that a calibration
//! that cannot come within a decision's margin of a rival stops early
//! (`Abandon`) instead of tempering to β = 1 for an answer nobody weighs.

use super::*;

/// Asked after each tempering step below β = 1 with an upper estimate of
/// the replicate's final log evidence; `true` stops the replicate there.
pub type Abandon<'a> = &'a (dyn Fn(f64) -> bool + Sync);

/// An upper estimate of log Z at β = 1 from the cloud at β (log-likelihoods
/// `loglik`, normalized weights `weights` of π_β) and log Z_β so far.
///
/// log Z₁ = log Z_β + log E_π_β[L^(1−β)] ≤ log Z_β + (1 − β) log sup L
/// (Jensen). sup L is estimated from the cloud as its best log-likelihood
/// plus that best's distance above the weighted mean: for a Gaussian
/// posterior under a flat prior, log L = log L* − q/(2β) with q ~ χ²_d
/// under π_β, so the mean falls d/(2β) below log L* and the best of the
/// cloud min q/(2β), which is less than d/(2β) for any cloud of more than a
/// couple of particles. Early in tempering, when the cloud is still spread
/// over the prior, the margin is wide (it grows as 1/β) and nothing stops;
/// it narrows as the cloud finds the likelihood's peak. A mode the cloud has
/// not found is beyond any estimate from it, as it is beyond the SMC run
/// itself.
pub(super) fn final_log_evidence_at_most(log_z: f64, beta: f64, loglik: &[f64], weights: &[f64]) -> f64 {
    let finite = || loglik.iter().zip(weights).filter(|(l, _)| l.is_finite());
    let best = finite().map(|(l, _)| *l).fold(f64::NEG_INFINITY, f64::max);
    let (mass, sum) = finite().fold((0.0, 0.0), |(m, s), (l, w)| (m + w, s + w * l));
    if !best.is_finite() || mass <= 0.0 {
        return f64::INFINITY;
    }
    let mean = sum / mass;
    log_z + (1.0 - beta) * (best + (best - mean))
}

impl Tempered<'_> {
    /// An abandoned replicate (`Abandon`): its cloud resampled at the β it
    /// stopped at, with no moves, and the upper estimate as its evidence.
    pub(super) fn abandon_replicate(
        &self,
        mut st: ReplicateState,
        weights: &[f64],
        (beta, reach): (f64, f64),
    ) -> ReplicateOutput {
        let relative_variance = relative_variance(&st.eve, st.stages, weights);
        let ancestors = multinomial_ancestors(weights, &mut st.master);
        let mut unique = ancestors.clone();
        unique.dedup();
        st.cloud.resample(&ancestors);
        let mut particles = vec![0.0; st.cloud.x.len()];
        for (u, out) in st.cloud.x.chunks(self.dim).zip(particles.chunks_mut(self.dim)) {
            self.prior.from_unbounded(u, out);
        }
        st.steps.push(SmcStep {
            beta,
            mcmc_steps: 0,
            acceptance: 0.0,
            group_acceptance: Vec::new(),
            mixture_acceptance: 0.0,
        });
        ReplicateOutput {
            particles,
            log_evidence: reach,
            relative_variance,
            steps: st.steps,
            likelihood_evaluations: st.evaluations,
            term_evaluations: st.term_evaluations,
            unique_fraction: unique.len() as f64 / self.n as f64,
            abandoned_at: Some(beta),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{ChiSquared, Distribution};

    /// A Gaussian likelihood of d parameters under a flat prior: π_β's
    /// log L is log L* − q/(2β) with q ~ χ²_d, and the exact final log
    /// evidence is log Z_β + (1 − β) log L* + (d/2) log β. The estimate
    /// must lie above it at every β of a typical tempering run, for clouds
    /// of 500 particles, and come within a few nats of it near β = 1.
    #[test]
    fn the_estimate_bounds_a_gaussian_posteriors_final_evidence() {
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(3);
        let (log_l_star, log_z_beta) = (-40.0, -7.0);
        for d in [1usize, 3, 8, 15] {
            let chi2 = ChiSquared::new(d as f64).unwrap();
            for beta in [1e-4, 1e-3, 1e-2, 0.1, 0.3, 0.7, 0.95] {
                for _ in 0..20 {
                    let loglik: Vec<f64> =
                        (0..500).map(|_| log_l_star - chi2.sample(&mut rng) / (2.0 * beta)).collect();
                    let weights = vec![1.0 / 500.0; 500];
                    let exact = log_z_beta + (1.0 - beta) * log_l_star + 0.5 * d as f64 * f64::ln(beta);
                    let estimate = final_log_evidence_at_most(log_z_beta, beta, &loglik, &weights);
                    assert!(estimate >= exact, "d = {d}, β = {beta}: {estimate} below the exact {exact}");
                    if beta >= 0.7 {
                        assert!(estimate - exact < 2.0 * d as f64, "d = {d}, β = {beta}: {estimate} vs {exact}");
                    }
                }
            }
        }
    }

    #[test]
    fn a_cloud_with_no_finite_likelihood_bounds_nothing() {
        let loglik = [f64::NEG_INFINITY, f64::NAN];
        assert_eq!(final_log_evidence_at_most(0.0, 0.5, &loglik, &[0.5, 0.5]), f64::INFINITY);
    }
}
