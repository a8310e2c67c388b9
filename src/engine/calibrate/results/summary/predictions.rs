//! Posterior-predictive bands of the model, the model with δ, and δ, on a
//! grid past the data and at the data (`predictions.parquet`).

use super::*;

/// Posterior-predictive bands at one x for one observable.
#[derive(Clone, Debug, PartialEq)]
pub struct PredictionRow {
    pub observable: String,
    /// "grid" for the prediction grid, "data" at measured points.
    pub kind: &'static str,
    pub x: f64,
    /// Model alone η(x, θ): 2.5, 16, 50, 84, 97.5 percentiles.
    pub model: [f64; 5],
    /// Model + δ.
    pub model_md: [f64; 5],
    /// δ alone (original units) and its posterior mean.
    pub delta: [f64; 5],
    pub delta_mean: f64,
    /// The true curve (config `[truth]`), NaN where unknown.
    pub truth: f64,
}

pub(super) const BAND_LEVELS: [f64; 5] = [0.025, 0.16, 0.5, 0.84, 0.975];

pub(super) fn bands(values: &mut [f64]) -> [f64; 5] {
    values.sort_by(|a, b| a.total_cmp(b));
    BAND_LEVELS.map(|q| diagnostics::quantile_sorted(values, q))
}

/// Bands of η and η + δ on a grid extending beyond the data, and at the data.
/// δ at new x is drawn from the GP conditional on the residuals at the data;
/// pointwise bands need only its marginals.
pub fn predictions(problem: &Problem, chains: &Chains, seed: u64) -> Result<Vec<PredictionRow>> {
    let cfg = &problem.analysis.predictions;
    let lik = &problem.likelihood;
    let n_theta = lik.n_theta;
    let all: Vec<&[f64]> = chains.rows().collect();
    let n_use = cfg.draws.min(all.len()).max(1);
    let stride = all.len() as f64 / n_use as f64;
    let draws: Vec<&[f64]> = (0..n_use).map(|i| all[(i as f64 * stride) as usize]).collect();
    let mut rows = Vec::new();
    for (b, block) in lik.blocks.iter().enumerate() {
        let x_max = cfg.x_max.unwrap_or(1.5 * block.x.iter().cloned().fold(f64::NEG_INFINITY, f64::max));
        let x_min = cfg.x_min.unwrap_or(block.x.iter().cloned().fold(0.0, f64::min));
        let npts = cfg.points.max(2);
        // An emulator knows only its training bins: no grid then.
        let mut xs: Vec<(f64, &'static str)> = if problem.simulator.predicts_any_x() {
            (0..npts).map(|i| (x_min + (x_max - x_min) * i as f64 / (npts - 1) as f64, "grid")).collect()
        } else {
            Vec::new()
        };
        xs.extend(block.x.iter().map(|&x| (x, "data")));
        let xq: Vec<f64> = xs.iter().map(|p| p.0).collect();
        let m = xq.len();
        let truth = problem.analysis.truth_curve(&block.name, &xq).unwrap_or_else(|| vec![f64::NAN; m]);
        // Per draw: η(xq) and δ(xq) samples, in original units.
        let per_draw: Vec<(Vec<f64>, Vec<f64>, Vec<f64>)> = draws
            .par_iter()
            .enumerate()
            .map(|(d, params)| {
                let mut rng =
                    Xoshiro256PlusPlus::seed_from_u64(seed ^ ((b as u64) << 40) ^ (d as u64).wrapping_mul(0x9E37_79B9));
                let theta = &params[..n_theta];
                let mut eta = vec![0.0; m];
                problem.simulator.predict(block.model_index, &xq, theta, &mut eta);
                let (delta, delta_mean) = match lik.kernel {
                    None => (vec![0.0; m], vec![0.0; m]),
                    Some(kernel) => conditional_delta(kernel, params, b, &xq, problem, &mut rng),
                };
                (eta, delta, delta_mean)
            })
            .collect();
        for (q, &(x, kind)) in xs.iter().enumerate() {
            let mut model: Vec<f64> = per_draw.iter().map(|d| d.0[q]).collect();
            let mut md: Vec<f64> = per_draw.iter().map(|d| d.0[q] + d.1[q]).collect();
            let mut delta: Vec<f64> = per_draw.iter().map(|d| d.1[q]).collect();
            let delta_mean = per_draw.iter().map(|d| d.2[q]).sum::<f64>() / per_draw.len() as f64;
            rows.push(PredictionRow {
                observable: block.name.clone(),
                kind,
                x,
                model: bands(&mut model),
                model_md: bands(&mut md),
                delta: bands(&mut delta),
                delta_mean,
                truth: truth[q],
            });
        }
    }
    Ok(rows)
}

/// One draw of δ(xq) and its conditional mean, given the data residuals (of
/// every observable, when the likelihood is joint).
pub(super) fn conditional_delta(
    kernel: DiscrepancyKernel,
    params: &[f64],
    b: usize,
    xq: &[f64],
    problem: &Problem,
    rng: &mut Xoshiro256PlusPlus,
) -> (Vec<f64>, Vec<f64>) {
    let lik = &problem.likelihood;
    let (block, hyper) = (&lik.blocks[b], lik.hyper_of(params, b));
    let m = xq.len();
    let (mut draw, mut mean) = (vec![0.0; m], vec![0.0; m]);
    // Per query point: the conditional mean kᵀ Σ⁻¹ r and kᵀ Σ⁻¹ k (standardized).
    let Some(solved) = conditional_moments(kernel, params, b, xq, problem) else {
        return (vec![f64::NAN; m], vec![f64::NAN; m]);
    };
    for (q, (mu, explained)) in solved.into_iter().enumerate() {
        let prior_var = {
            let p = pow_r(block.input.apply(xq[q]), hyper[2]);
            let s2 = if kernel == DiscrepancyKernel::KernelI { hyper[3] * hyper[3] } else { 0.0 };
            s2 + hyper[0] * hyper[0] * p * p
        };
        let var = (prior_var - explained).max(0.0);
        let z: f64 = StandardNormal.sample(rng);
        mean[q] = mu * block.scale;
        draw[q] = (mu + var.sqrt() * z) * block.scale;
    }
    (draw, mean)
}

/// `(kᵀ Σ⁻¹ r, kᵀ Σ⁻¹ k)` at each query point, k the covariance of δ_b there
/// with block b's points (zero elsewhere): by the structured factors when the
/// joint likelihood has them (no N × N factorization), else densely.
fn conditional_moments(
    kernel: DiscrepancyKernel,
    params: &[f64],
    b: usize,
    xq: &[f64],
    problem: &Problem,
) -> Option<Vec<(f64, f64)>> {
    let lik = &problem.likelihood;
    let (block, hyper) = (&lik.blocks[b], lik.hyper_of(params, b));
    let cross =
        |x: f64, out: &mut [f64]| discrepancy_cross_cov(kernel, hyper, &block.kernel_x, &[block.input.apply(x)], out);
    if let Some((factored, mut alpha)) = lik.structured_system(params) {
        factored.solve_in_place(&mut alpha);
        let rows = lik.layout()?.rows(b);
        let mut k = vec![0.0; block.len()];
        return Some(
            xq.iter()
                .map(|&x| {
                    cross(x, &mut k);
                    let mu: f64 = k.iter().zip(&alpha[rows.clone()]).map(|(a, b)| a * b).sum();
                    (mu, factored.block_quadratic(b, &mut k))
                })
                .collect(),
        );
    }
    // The covariance of the standardized residuals, and where block b sits in it.
    let (lower, mut alpha, rows) = match lik.joint_system(params) {
        Some((lower, resid)) => (lower, resid, lik.layout().map(|j| j.rows(b)).unwrap_or_default()),
        None => {
            let n = block.len();
            let theta = &params[..lik.n_theta];
            let mut eta = vec![0.0; n];
            problem.simulator.predict(block.model_index, &block.x, theta, &mut eta);
            let mut lower = vec![0.0; n * n];
            discrepancy_cross_cov(kernel, hyper, &block.kernel_x, &block.kernel_x, &mut lower);
            problem.simulator.add_model_covariance(
                block.model_index,
                &block.x,
                theta,
                1.0 / (block.scale * block.scale),
                &mut lower,
            );
            block.add_data_covariance(1.0 / (block.scale * block.scale), &mut lower);
            (lower, (0..n).map(|i| (block.y[i] - eta[i]) / block.scale).collect(), 0..n)
        }
    };
    let n = alpha.len();
    let mut ws = CholeskyWorkspace::new(n);
    ws.factor.copy_from_slice(&lower);
    ws.factorize().ok()?;
    ws.solve_in_place(&mut alpha);
    // δ_b is correlated with block b's residuals only: zero elsewhere.
    let mut kq = vec![0.0; n];
    Some(
        xq.iter()
            .map(|&x| {
                kq.fill(0.0);
                cross(x, &mut kq[rows.clone()]);
                let mu: f64 = kq.iter().zip(&alpha).map(|(a, b)| a * b).sum();
                ws.solve_lower_in_place(&mut kq);
                (mu, kq.iter().map(|v| v * v).sum::<f64>())
            })
            .collect(),
    )
}

pub fn predictions_frame(rows: &[PredictionRow]) -> Result<DataFrame> {
    let names = ["q025", "q16", "median", "q84", "q975"];
    let mut cols: Vec<Column> = vec![
        Column::new("observable".into(), rows.iter().map(|r| r.observable.as_str()).collect::<Vec<_>>()),
        Column::new("kind".into(), rows.iter().map(|r| r.kind).collect::<Vec<_>>()),
        Column::new("x".into(), rows.iter().map(|r| r.x).collect::<Vec<_>>()),
    ];
    for (prefix, get) in [
        ("model", (|r: &PredictionRow| r.model) as fn(&PredictionRow) -> [f64; 5]),
        ("model_md", |r: &PredictionRow| r.model_md),
        ("delta", |r: &PredictionRow| r.delta),
    ] {
        for (k, n) in names.iter().enumerate() {
            cols.push(Column::new(format!("{prefix}_{n}").into(), rows.iter().map(|r| get(r)[k]).collect::<Vec<_>>()));
        }
    }
    cols.push(Column::new("delta_mean".into(), rows.iter().map(|r| r.delta_mean).collect::<Vec<_>>()));
    cols.push(Column::new("truth".into(), rows.iter().map(|r| r.truth).collect::<Vec<_>>()));
    Ok(DataFrame::new(rows.len(), cols)?)
}
