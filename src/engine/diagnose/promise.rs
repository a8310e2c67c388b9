//! The order in which declared candidates are calibrated: most promising
//! first, so the leader is known early and a later candidate far behind it
//! stops while it tempers (`smc::Abandon`) instead of being sampled in full
//! before the leader is met.
//!
//! A candidate's promise is a cheap stand-in for its log evidence: its best
//! log-likelihood without MD from a short Nelder–Mead search (started at the
//! base fit's medians, its own parameters at their priors' centres), less
//! the BIC's ½·p·ln n for its p parameters over n points, plus its prior log
//! odds. The order changes which fits stop early, never a fit itself: each
//! candidate keeps the seed of its declared position.

use crate::engine::calibrate::{Analysis, Overrides, Problem};
use crate::engine::gp::DiscrepancyKernel;
use crate::engine::model::CandidateModel;
use argmin::core::{CostFunction, Executor};
use argmin::solver::neldermead::NelderMead;
use std::collections::BTreeMap;

/// Likelihood evaluations per parameter of one candidate's search: a
/// ranking needs the basin, not the optimum's last digit.
const EVALUATIONS_PER_PARAMETER: u64 = 40;

/// Indices of `candidates` from most to least promising; ties (and
/// candidates that cannot be computed) keep their declared order.
pub(super) fn order(
    analysis: &Analysis,
    overrides: &Overrides,
    candidates: &[(CandidateModel, f64)],
    base_medians: &BTreeMap<String, f64>,
) -> Vec<usize> {
    let scores: Vec<f64> = candidates
        .iter()
        .map(|(c, odds)| promise(analysis, overrides, c, base_medians).map_or(f64::NEG_INFINITY, |p| p + odds))
        .collect();
    let mut order: Vec<usize> = (0..candidates.len()).collect();
    // A stable sort keeps the declared order among equals.
    order.sort_by(|a, b| scores[*b].total_cmp(&scores[*a]));
    order
}

/// The candidate's best log-likelihood found less ½·p·ln n; None when its
/// problem cannot be built or no point of its prior computes.
fn promise(
    analysis: &Analysis,
    overrides: &Overrides,
    candidate: &CandidateModel,
    base_medians: &BTreeMap<String, f64>,
) -> Option<f64> {
    let no_md = Overrides { kernel: Some(DiscrepancyKernel::choice(None)), ..overrides.clone() };
    let problem = Problem::new(&analysis.with_candidate(candidate), &no_md).ok()?;
    let prior = &problem.prior;
    let start: Vec<f64> = (0..prior.dim())
        .map(|i| {
            let centre = 0.5 * (prior.lower[i] + prior.upper[i]);
            base_medians
                .get(&prior.names[i])
                .copied()
                .filter(|m| prior.lower[i] < *m && *m < prior.upper[i])
                .unwrap_or(centre)
        })
        .collect();
    let best = best_log_likelihood(&problem, start)?;
    let points: usize = problem.likelihood.blocks.iter().map(|b| b.x.len()).sum();
    Some(best - 0.5 * prior.dim() as f64 * (points.max(1) as f64).ln())
}

/// Negative log-likelihood over the prior box (outside it, or where the
/// model fails, a cost no point inside can have).
struct Misfit<'a>(&'a Problem);

const OUTSIDE: f64 = f64::MAX;

impl CostFunction for Misfit<'_> {
    type Param = Vec<f64>;
    type Output = f64;
    fn cost(&self, x: &Self::Param) -> Result<f64, argmin::core::Error> {
        if !self.0.prior.contains(x) {
            return Ok(OUTSIDE);
        }
        let l = self.0.likelihood.log_likelihood(x);
        Ok(if l.is_finite() { -l } else { OUTSIDE })
    }
}

fn best_log_likelihood(problem: &Problem, start: Vec<f64>) -> Option<f64> {
    let prior = &problem.prior;
    let misfit = Misfit(problem);
    if prior.dim() == 0 {
        return misfit.cost(&start).ok().filter(|c| *c < OUTSIDE).map(|c| -c);
    }
    // The simplex spans a tenth of each prior's width, pointing inward from the start.
    let mut simplex = vec![start.clone()];
    for i in 0..prior.dim() {
        let step = 0.1 * (prior.upper[i] - prior.lower[i]);
        let mut vertex = start.clone();
        vertex[i] += if start[i] + step < prior.upper[i] { step } else { -step };
        simplex.push(vertex);
    }
    let solver = NelderMead::new(simplex).with_sd_tolerance(1e-6).ok()?;
    let iterations = EVALUATIONS_PER_PARAMETER * prior.dim() as u64;
    let result = Executor::new(misfit, solver).configure(|s| s.max_iters(iterations)).timer(false).run().ok()?;
    let cost = result.state().best_cost;
    (cost < OUTSIDE).then_some(-cost)
}
