//! How well the model alone fits at the posterior median: the generalized χ²
//! with the data errors and the emulator's covariance, and the emulator's
//! share of the predictive variance per observable.

use super::*;

pub fn fit_quality(problem: &Problem, theta: &[f64]) -> FitQuality {
    let mut per_observable = BTreeMap::new();
    let mut chi2 = 0.0;
    let mut n = 0;
    let mut per_observable_share = BTreeMap::new();
    for b in &problem.likelihood.blocks {
        let mut model_share = 0.0;
        let n_b = b.len();
        let mut eta = vec![0.0; n_b];
        problem.simulator.predict(b.model_index, &b.x, theta, &mut eta);
        let mut r: Vec<f64> = (0..n_b).map(|i| b.y[i] - eta[i]).collect();
        let c = if problem.simulator.has_model_covariance() || !b.diagonal_data() {
            let mut model = vec![0.0; n_b * n_b];
            problem.simulator.add_model_covariance(b.model_index, &b.x, theta, 1.0, &mut model);
            let mut ws = crate::engine::gp::CholeskyWorkspace::new(n_b);
            ws.factor.fill(0.0);
            b.add_data_covariance(1.0, &mut ws.factor);
            let data_diag: Vec<f64> = (0..n_b).map(|i| ws.factor[i * n_b + i]).collect();
            for (f, m) in ws.factor.iter_mut().zip(&model) {
                *f += m;
            }
            match ws.factorize() {
                Ok(_) => {
                    model_share += trace_of_product(&model, &ws.inverse(), n_b);
                    ws.solve_lower_in_place(&mut r);
                    r.iter().map(|z| z * z).sum()
                }
                Err(_) => {
                    model_share +=
                        (0..n_b).map(|i| model[i * n_b + i] / (model[i * n_b + i] + data_diag[i])).sum::<f64>();
                    f64::INFINITY
                }
            }
        } else {
            (0..n_b).map(|i| (r[i] / b.error[i]).powi(2)).sum()
        };
        per_observable.insert(b.name.clone(), c);
        per_observable_share.insert(b.name.clone(), model_share / n_b.max(1) as f64);
        chi2 += c;
        n += b.len();
    }
    // Joint: the χ² of all points together (the per-observable values stay each block's own).
    if let Some(total) = joint_chi2(problem, theta) {
        chi2 = total;
    }
    let dof = n.saturating_sub(theta.len()).max(1);
    let model_variance_share = worst_share(per_observable_share.values().copied());
    FitQuality {
        chi2,
        dof,
        chi2_per_dof: chi2 / dof as f64,
        per_observable,
        model_variance_share,
        per_observable_share,
    }
}

/// The largest share; one that is not a number (an emulator whose variance
/// is NaN or infinite) counts as 1, since nothing shows the fit rests on the
/// data (`f64::max` would silently drop it and call the fit data-driven).
pub(super) fn worst_share(shares: impl Iterator<Item = f64>) -> f64 {
    shares.map(|v| if v.is_finite() { v } else { 1.0 }).fold(0.0, f64::max)
}

/// `tr(A B)` for symmetric n × n matrices, A given by its lower triangle and
/// B in full (both column-major).
pub(super) fn trace_of_product(a_lower: &[f64], b: &[f64], n: usize) -> f64 {
    let mut t = 0.0;
    for j in 0..n {
        t += a_lower[j * n + j] * b[j * n + j];
        for i in j + 1..n {
            t += 2.0 * a_lower[j * n + i] * b[j * n + i];
        }
    }
    t
}

/// `rᵀ C⁻¹ r` over all points with the joint covariance of the data and the
/// model (no δ); `None` for the block form.
pub(super) fn joint_chi2(problem: &Problem, theta: &[f64]) -> Option<f64> {
    let (lower, mut r) = problem.likelihood.joint_model_system(theta)?;
    let mut ws = crate::engine::gp::CholeskyWorkspace::new(r.len());
    ws.factor.copy_from_slice(&lower);
    Some(match ws.factorize() {
        Ok(_) => {
            ws.solve_lower_in_place(&mut r);
            r.iter().map(|z| z * z).sum()
        }
        Err(_) => f64::INFINITY,
    })
}
