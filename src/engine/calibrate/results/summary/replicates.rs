//! What ArviZ needs beyond the draws: each draw's log-likelihood and log
//! prior (its `sample_stats` and `log_likelihood` groups), and replicated
//! data sets drawn from the posterior predictive at the measured points
//! (`posterior_predictive.parquet`, its `posterior_predictive` group).

use super::*;
use crate::engine::calibrate::likelihood::block::ObservableBlock;

/// Columns added to `posterior.parquet` beside the draws, row for row:
/// `log_likelihood` and `log_prior` (the sampler's target is their sum), and
/// `log_likelihood.<observable>` per observable when the observables are
/// independent (each in data units, the terms summing to the total).
pub fn log_density_columns(problem: &Problem, chains: &Chains) -> Vec<(String, Vec<f64>)> {
    let lik = &problem.likelihood;
    // The block form's terms are independent; a joint likelihood has one.
    let separable = lik.layout().is_none();
    let n_terms = if separable { lik.blocks.len() } else { 0 };
    let rows: Vec<&[f64]> = chains.rows().collect();
    let per_row: Vec<(f64, f64, Vec<f64>)> = rows
        .par_iter()
        .map(|params| {
            let mut terms = vec![0.0; n_terms];
            let total =
                if separable { lik.log_likelihood_terms(params, &mut terms) } else { lik.log_likelihood(params) };
            // The block terms are in standardized units; each takes its own
            // share of the standardization's Jacobian, so they sum to the total.
            for (t, block) in terms.iter_mut().zip(&lik.blocks) {
                *t -= block.len() as f64 * block.scale.ln();
            }
            (total, problem.prior.log_density(params), terms)
        })
        .collect();
    let mut cols = vec![
        ("log_likelihood".to_string(), per_row.iter().map(|r| r.0).collect()),
        ("log_prior".to_string(), per_row.iter().map(|r| r.1).collect()),
    ];
    for (b, block) in lik.blocks.iter().enumerate().take(n_terms) {
        cols.push((format!("log_likelihood.{}", block.name), per_row.iter().map(|r| r.2[b]).collect()));
    }
    cols
}

/// Replicated measurements `y_rep = η(x, θ) + δ(x) + ε` at the measured
/// points for an evenly spaced subset of each chain's draws (about
/// `[predictions] draws` in all): δ from its GP conditional on the data, ε
/// from each observable's own data covariance (its errors and `[data]
/// covariance` within the observable). Long table: `chain, draw, observable,
/// x, y` (`draw` indexes the chain's draws in `posterior.parquet`).
pub fn replicates_frame(problem: &Problem, chains: &Chains, seed: u64) -> Result<DataFrame> {
    let lik = &problem.likelihood;
    let picks = thinned_draws(chains, problem.analysis.predictions.draws);
    let noise: Vec<Option<Vec<f64>>> = lik.blocks.iter().map(noise_factor).collect();
    let per_pick: Vec<Vec<Vec<f64>>> = picks
        .par_iter()
        .enumerate()
        .map(|(d, &(chain, draw))| {
            let params = &chains.chains[chain][draw * chains.dim..(draw + 1) * chains.dim];
            let mut rng =
                Xoshiro256PlusPlus::seed_from_u64(seed ^ 0x005E_ED0F_DA7A ^ (d as u64).wrapping_mul(0x9E37_79B9));
            (0..lik.blocks.len()).map(|b| replicate_block(problem, params, b, noise[b].as_deref(), &mut rng)).collect()
        })
        .collect();
    let (mut ch, mut dr, mut obs, mut xs, mut ys) = (vec![], vec![], vec![], vec![], vec![]);
    for (&(chain, draw), blocks) in picks.iter().zip(&per_pick) {
        for (block, y) in lik.blocks.iter().zip(blocks) {
            for (&x, &v) in block.x.iter().zip(y) {
                ch.push(chain as u32);
                dr.push(draw as u32);
                obs.push(block.name.clone());
                xs.push(x);
                ys.push(v);
            }
        }
    }
    Ok(DataFrame::new(
        ys.len(),
        vec![
            Column::new("chain".into(), ch),
            Column::new("draw".into(), dr),
            Column::new("observable".into(), obs),
            Column::new("x".into(), xs),
            Column::new("y".into(), ys),
        ],
    )?)
}

/// `(chain, draw)` of about `total` draws, the same number from every chain,
/// evenly spaced within each, so that ArviZ sees a chain × draw array.
fn thinned_draws(chains: &Chains, total: usize) -> Vec<(usize, usize)> {
    let lengths: Vec<usize> = chains.chains.iter().map(|c| chains.draws_in(c)).collect();
    let shortest = lengths.iter().copied().min().unwrap_or(0);
    let per_chain = total.div_ceil(lengths.len().max(1)).max(1).min(shortest);
    let mut picks = Vec::with_capacity(per_chain * lengths.len());
    for (chain, &len) in lengths.iter().enumerate() {
        let stride = len as f64 / per_chain as f64;
        picks.extend((0..per_chain).map(|i| (chain, (i as f64 * stride) as usize)));
    }
    picks
}

/// The lower Cholesky factor (column-major) of one observable's data
/// covariance, errors² on the diagonal plus its `[data] covariance`; `None`
/// when the errors are independent (ε is then drawn point by point).
fn noise_factor(block: &ObservableBlock) -> Option<Vec<f64>> {
    let cov = block.covariance.as_ref()?;
    let n = block.len();
    let mut ws = CholeskyWorkspace::new(n);
    ws.factor.copy_from_slice(cov);
    for (i, e) in block.error.iter().enumerate() {
        ws.factor[i * n + i] += e * e;
    }
    ws.factorize().ok()?;
    Some(ws.factor)
}

fn replicate_block(
    problem: &Problem,
    params: &[f64],
    b: usize,
    noise: Option<&[f64]>,
    rng: &mut Xoshiro256PlusPlus,
) -> Vec<f64> {
    let lik = &problem.likelihood;
    let block = &lik.blocks[b];
    let n = block.len();
    let mut y = vec![0.0; n];
    problem.simulator.predict(block.model_index, &block.x, &params[..lik.n_theta], &mut y);
    if let Some(kernel) = lik.kernel {
        let (delta, _) = conditional_delta(kernel, params, b, &block.x, problem, rng);
        y.iter_mut().zip(&delta).for_each(|(v, d)| *v += d);
    }
    let z: Vec<f64> = (0..n).map(|_| StandardNormal.sample(rng)).collect();
    match noise {
        Some(factor) => {
            for i in 0..n {
                y[i] += (0..=i).map(|j| factor[j * n + i] * z[j]).sum::<f64>();
            }
        }
        None => y.iter_mut().zip(&block.error).zip(&z).for_each(|((v, e), z)| *v += e * z),
    }
    y
}
