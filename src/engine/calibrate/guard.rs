//! Before sampling: a likelihood that is not finite anywhere leaves a
//! tempered sampler crawling (β never reaches 1) and an ensemble returning
//! prior draws, with nothing said. [`check`] evaluates the likelihood at a
//! spread of prior draws and stops at once, naming the observable and, where
//! it can tell, why.

use super::problem::Problem;
use anyhow::{bail, Result};
use rand::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;

/// Prior draws tried.
pub const DRAWS: usize = 64;

/// The model itself cannot be computed over the data at any prior draw
/// tried (an ODE that blows up before the data's latest time): no fit of
/// it, with or without MD, can be made, though a model with a term added
/// may be (`diagnose` then judges the candidates alone).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct NotComputable(pub String);

/// An error unless every observable's likelihood term, and the whole
/// likelihood, is finite at one or more of [`DRAWS`] prior draws. Its own
/// random stream leaves the sampler's untouched.
pub fn check(problem: &Problem, seed: u64) -> Result<()> {
    let lik = &problem.likelihood;
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed ^ 0x6A09_E667_F3BC_C908);
    let draws: Vec<Vec<f64>> = (0..DRAWS)
        .map(|_| {
            let mut x = vec![0.0; problem.prior.dim()];
            problem.prior.sample(&mut rng, &mut x);
            x
        })
        .collect();
    for b in 0..lik.blocks.len() {
        if !draws.iter().any(|d| lik.log_likelihood_term(d, b).is_finite()) {
            let (why, model) = why_not_finite(problem, b, &draws[0]);
            if model {
                return Err(NotComputable(why).into());
            }
            bail!("{why}");
        }
    }
    if !draws.iter().any(|d| lik.log_likelihood(d).is_finite()) {
        bail!("{}: the likelihood is not finite at any of {DRAWS} draws from the prior, though each observable's term is somewhere; narrow the prior bounds to where the model is defined", problem.data_path.display());
    }
    Ok(())
}

/// What makes block `b`'s term infinite everywhere, as far as it can tell,
/// and whether it is the model's prediction itself.
fn why_not_finite(problem: &Problem, b: usize, draw: &[f64]) -> (String, bool) {
    let lik = &problem.likelihood;
    let block = &lik.blocks[b];
    let (file, name) = (problem.data_path.display(), &block.name);
    let min_input = block.kernel_x.iter().cloned().fold(f64::INFINITY, f64::min);
    if lik.kernel.is_some() && min_input < 0.0 {
        let x = block.x[block.kernel_x.iter().position(|&k| k == min_input).unwrap_or(0)];
        let why = format!(
            "{file}: observable '{name}': the discrepancy kernel's (x·x')^r factor needs x ≥ 0, but x = {x:e} gives the kernel input {min_input:e}; give [discrepancy.inputs.{name}] a shift (and scale) so that (x + shift)/scale ≥ 0, e.g. shift = {}, or rescale x",
            -block.x.iter().cloned().fold(f64::INFINITY, f64::min)
        );
        return (why, false);
    }
    let theta = &draw[..lik.n_theta];
    let mut eta = vec![0.0; block.len()];
    let failures = lik.simulator.failures();
    lik.simulator.predict(block.model_index, &block.x, theta, &mut eta);
    // A model that says it failed (an ODE that did not integrate) is named as such.
    let failed = if lik.simulator.failures() > failures {
        "; the model reports that it could not be computed there (an ODE whose integration failed before the data's latest x: more steps than [model.solver] max_steps, a step size too small, or a rate that is not finite)"
    } else {
        ""
    };
    if let Some(i) = eta.iter().position(|v| !v.is_finite()) {
        let why = format!(
            "{file}: observable '{name}': the model's prediction is not finite at any of {DRAWS} prior draws tried (e.g. {} at x = {:e} for {} = {:?}){failed}; check the model, or narrow the prior to where it is defined",
            eta[i],
            block.x[i],
            lik.simulator.parameter_names().join(", "),
            theta
        );
        return (why, true);
    }
    if lik.kernel.is_none() && !lik.simulator.has_model_covariance() {
        // A diagonal covariance of positive errors: only (y − η)/σ can overflow.
        let smallest = block.error.iter().cloned().fold(f64::INFINITY, f64::min);
        return (format!("{file}: observable '{name}': the residuals in units of the errors overflow at every one of {DRAWS} prior draws tried (smallest error {smallest:e}); check the errors' units"), false);
    }
    (format!("{file}: observable '{name}': the likelihood is not finite at any of {DRAWS} prior draws tried (no positive-definite covariance from the errors, the discrepancy bounds and the model's covariance); check the errors and [discrepancy.bounds]"), false)
}
