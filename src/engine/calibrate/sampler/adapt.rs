//! Convergence by default. Where an SMC calibration with its configured
//! settings has not converged (some parameter's R̂ above 1.01 or its bulk or
//! tail ESS below 400), it is sampled again with more: twice the particles
//! per replicate when the replicates disagree (R̂), twice the final
//! random-walk sweeps and final mixture proposals when the draws hold too
//! few independent ones (ESS; twice the particles instead when there are
//! fewer than 800 draws in all), both when both fail. A config that chose
//! small settings for speed turns this off with `[sampler] adapt = false`. At most two more runs,
//! and none whose expected cost would take the total beyond eight times the
//! first run's likelihood evaluations. The last run's draws are the result;
//! every run is listed in `summary.json` (`diagnostics.adaptation`) and said
//! as it happens. Each run after the first checkpoints in its own folder
//! (`<checkpoint>/adapt_<k>`) under its own key, so an interrupted run
//! resumes where it was.

use super::chains::Chains;
use super::checkpoint::Checkpointing;
use super::diagnostics::{self, ESS_MIN, RHAT_MAX};
use super::smc::SmcSettings;

/// Runs after the first, at most.
pub const MAX_RERUNS: usize = 2;
/// Likelihood evaluations of all runs together, at most, in units of the first run's.
pub const BUDGET: f64 = 8.0;

/// One run of an adapted calibration: its settings and how it ended.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Attempt {
    pub particles: usize,
    pub final_steps_per_dim: f64,
    pub final_mixture_proposals: usize,
    pub max_rhat: f64,
    pub min_ess: f64,
    pub evaluations: u64,
}

/// The worst R̂ and ESS over the parameters of a run.
#[derive(Clone, Copy, Debug)]
pub struct Convergence {
    pub max_rhat: f64,
    pub min_ess: f64,
}

impl Convergence {
    pub fn of(chains: &Chains) -> Convergence {
        let (mut max_rhat, mut min_ess) = (0.0f64, f64::INFINITY);
        for p in 0..chains.dim {
            let d = diagnostics::diagnose_param(&chains.names[p], &chains.param_chains(p));
            max_rhat = max_rhat.max(if d.rhat.is_finite() { d.rhat } else { f64::INFINITY });
            let ess = d.ess_bulk.min(d.ess_tail);
            min_ess = min_ess.min(if ess.is_finite() { ess } else { 0.0 });
        }
        Convergence { max_rhat, min_ess }
    }

    pub fn converged(&self) -> bool {
        self.max_rhat <= RHAT_MAX && self.min_ess >= ESS_MIN
    }
}

/// The settings of the next run after `last` ended with `c`, and the factor
/// by which its cost is expected to grow.
pub fn escalate(last: &SmcSettings, c: &Convergence) -> (SmcSettings, f64) {
    let mut next = last.clone();
    let mut growth = 1.0;
    if c.max_rhat > RHAT_MAX {
        next.particles = last.particles * 2;
        growth *= 2.0;
    }
    let draws = last.particles * last.replicates.max(1);
    if c.min_ess < ESS_MIN && c.max_rhat <= RHAT_MAX && (draws as f64) < 2.0 * ESS_MIN {
        // Fewer draws than the ESS asked for can hold: more particles, not more moves.
        next.particles = last.particles * 2;
        growth *= 2.0;
    } else if c.min_ess < ESS_MIN {
        next.final_steps_per_dim = (last.final_steps_per_dim * 2.0).max(1.0);
        next.final_mixture_proposals = (last.final_mixture_proposals * 2).max(1);
        growth *= 2.0;
    }
    (next, growth)
}

/// Whether a run expected to cost `growth` times the last one (`last`
/// evaluations) stays within the budget, given `spent` so far and the
/// first run's `first`.
pub fn affordable(first: u64, spent: u64, last: u64, growth: f64) -> bool {
    (spent as f64 + growth * last as f64) <= BUDGET * first as f64
}

/// The checkpointing of rerun `k`: its own folder and key.
pub fn rerun_checkpoint(ck: &Checkpointing, k: usize) -> Checkpointing {
    let mut rerun = ck.clone();
    rerun.dir = ck.dir.join(format!("adapt_{k}"));
    rerun.key = format!("{}|adapt_{k}", ck.key);
    rerun
}

impl Attempt {
    pub fn new(settings: &SmcSettings, c: &Convergence, evaluations: u64) -> Attempt {
        Attempt {
            particles: settings.particles,
            final_steps_per_dim: settings.final_steps_per_dim,
            final_mixture_proposals: settings.final_mixture_proposals,
            max_rhat: c.max_rhat,
            min_ess: c.min_ess,
            evaluations,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn more_particles_for_r_hat_more_final_moves_for_ess_within_the_budget() {
        let base = SmcSettings::default();
        let (next, g) = escalate(&base, &Convergence { max_rhat: 1.05, min_ess: 900.0 });
        assert_eq!((next.particles, next.final_steps_per_dim, g), (4000, base.final_steps_per_dim, 2.0));
        let (next, g) = escalate(&base, &Convergence { max_rhat: 1.0, min_ess: 100.0 });
        assert_eq!((next.particles, next.final_mixture_proposals, g), (2000, 20, 2.0));
        assert_eq!(next.final_steps_per_dim, 2.0 * base.final_steps_per_dim);
        let (_, g) = escalate(&base, &Convergence { max_rhat: 1.2, min_ess: 100.0 });
        assert_eq!(g, 4.0);
        // 1 + 2 + 4 fits in 8; 1 + 4 + 16 does not.
        assert!(affordable(100, 100, 100, 2.0) && affordable(100, 300, 200, 2.0));
        assert!(affordable(100, 100, 100, 4.0) && !affordable(100, 500, 400, 4.0));
        // 2 × 150 draws cannot hold an ESS of 400, whatever the moves.
        let few = SmcSettings { particles: 150, replicates: 2, ..SmcSettings::default() };
        let (next, g) = escalate(&few, &Convergence { max_rhat: 1.0, min_ess: 250.0 });
        assert_eq!((next.particles, next.final_steps_per_dim, g), (300, few.final_steps_per_dim, 2.0));
    }
}
