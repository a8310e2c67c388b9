//! Fisher information and Cramér–Rao bounds of θ for the model without MD:
//! the smallest spread any unbiased analysis of the data can reach, which
//! `diagnose` sets beside the posterior's.

use crate::engine::calibrate::likelihood::block::ObservableBlock;
use crate::engine::calibrate::likelihood::MdLikelihood;
use crate::engine::gp::CholeskyWorkspace;

/// Fisher information of θ for the model without MD at `theta`,
/// `F = Jᵀ C⁻¹ J` (column-major d × d) with C the data's covariance (per
/// block, or joint), in standardized units (the scales cancel), with the
/// Jacobian by central differences of step `steps[k]` in θ_k. `None` when
/// the model carries its own θ-dependent covariance (an emulator): that
/// dependence carries information this form leaves out, so it would be no bound.
pub fn information(lik: &MdLikelihood, theta: &[f64], steps: &[f64]) -> Option<Vec<f64>> {
    if lik.has_model_covariance() {
        return None;
    }
    let d = lik.n_theta;
    let jacobians: Vec<Vec<f64>> = lik.blocks.iter().map(|b| standardized_jacobian(lik, b, theta, steps)).collect();
    let whitened: Vec<(Vec<f64>, usize)> = match lik.layout() {
        Some(joint) => {
            let n = joint.len();
            let mut whole = vec![0.0; n * d];
            for (b, jac) in jacobians.iter().enumerate() {
                let nb = lik.blocks[b].len();
                for k in 0..d {
                    whole[k * n + joint.offsets[b]..k * n + joint.offsets[b] + nb]
                        .copy_from_slice(&jac[k * nb..(k + 1) * nb]);
                }
            }
            vec![(whiten(joint.data.clone(), n, whole, d)?, n)]
        }
        None => {
            let mut out = Vec::new();
            for (block, jac) in lik.blocks.iter().zip(jacobians) {
                let nb = block.len();
                let mut lower = vec![0.0; nb * nb];
                block.add_data_covariance(1.0 / (block.scale * block.scale), &mut lower);
                out.push((whiten(lower, nb, jac, d)?, nb));
            }
            out
        }
    };
    let mut fisher = vec![0.0; d * d];
    for (w, n) in &whitened {
        for a in 0..d {
            for b in 0..d {
                fisher[a + b * d] += (0..*n).map(|i| w[i + a * n] * w[i + b * n]).sum::<f64>();
            }
        }
    }
    Some(fisher)
}

/// `∂η/∂θ_k / scale` at the block's points, column-major n × d.
fn standardized_jacobian(lik: &MdLikelihood, block: &ObservableBlock, theta: &[f64], steps: &[f64]) -> Vec<f64> {
    let (n, d) = (block.len(), lik.n_theta);
    let (mut up, mut down) = (vec![0.0; n], vec![0.0; n]);
    let mut jac = vec![0.0; n * d];
    let mut shifted = theta.to_vec();
    for k in 0..d {
        shifted[k] = theta[k] + steps[k];
        lik.simulator.predict(block.model_index, &block.x, &shifted, &mut up);
        shifted[k] = theta[k] - steps[k];
        lik.simulator.predict(block.model_index, &block.x, &shifted, &mut down);
        shifted[k] = theta[k];
        for i in 0..n {
            jac[i + k * n] = (up[i] - down[i]) / (2.0 * steps[k] * block.scale);
        }
    }
    jac
}

/// Cramér–Rao standard deviations of θ at `theta`: the smallest spread any
/// unbiased analysis of these data can reach with this model, `sqrt(diag F⁻¹)`.
/// `None` as for `information`, or when F is singular (parameters
/// the data cannot tell apart, such as g and a constant extra force).
pub fn cramer_rao_sd(lik: &MdLikelihood, theta: &[f64], steps: &[f64]) -> Option<Vec<f64>> {
    let d = lik.n_theta;
    let fisher = information(lik, theta, steps)?;
    let mut chol = CholeskyWorkspace::new(d);
    chol.factor.copy_from_slice(&fisher);
    if !chol.factorize_exact() {
        return None;
    }
    let inv = chol.inverse();
    let sd: Vec<f64> = (0..d).map(|k| inv[k + k * d].sqrt()).collect();
    sd.iter().all(|v| v.is_finite()).then_some(sd)
}

/// `L⁻¹ J` for the d columns of `jac` (column-major n × d), with `L Lᵀ` the
/// covariance whose lower triangle is `lower`: then `Σ_i` of the products of
/// two columns is `Jᵀ C⁻¹ J`. `None` if the covariance is not positive definite.
fn whiten(lower: Vec<f64>, n: usize, mut jac: Vec<f64>, d: usize) -> Option<Vec<f64>> {
    let mut chol = CholeskyWorkspace::new(n);
    chol.factor.copy_from_slice(&lower);
    if !chol.factorize_exact() {
        return None;
    }
    for k in 0..d {
        chol.solve_lower_in_place(&mut jac[k * n..(k + 1) * n]);
    }
    Some(jac)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::calibrate::likelihood::data_covariance::test_support::*;

    /// The line's Fisher information is Jᵀ Σ⁻¹ J in closed form, with a
    /// covariance within block a and block b's errors alone.
    #[test]
    fn the_fisher_information_is_the_closed_form_with_a_covariance() {
        let lik = line_with_a_covariance();
        let theta = [1.0, 0.95];
        let (s11, s12, s22): (f64, f64, f64) = (0.015, 0.012, 0.04);
        let det = s11 * s22 - s12 * s12;
        // Fisher information of the line: Jᵀ Σ⁻¹ J, J = [[1, x]] per point.
        let f = information(&lik, &theta, &[1e-3, 1e-3]).unwrap();
        let inv = [s22 / det, -s12 / det, s11 / det];
        let (xa, xb) = ([0.0, 1.0], [0.0, 2.0]);
        let fa = |p: usize, q: usize| {
            let j = |i: usize, k: usize| if k == 0 { 1.0 } else { xa[i] };
            j(0, p) * (inv[0] * j(0, q) + inv[1] * j(1, q)) + j(1, p) * (inv[1] * j(0, q) + inv[2] * j(1, q))
        };
        let fb = |p: usize, q: usize| {
            (0..2).map(|i| if p == 0 { 1.0 } else { xb[i] } * if q == 0 { 1.0 } else { xb[i] } / 0.01).sum::<f64>()
        };
        for p in 0..2 {
            for q in 0..2 {
                let expect = fa(p, q) + fb(p, q);
                assert!(
                    (f[p + 2 * q] - expect).abs() < 1e-6 * expect.abs().max(1.0),
                    "F[{p},{q}] = {} vs {expect}",
                    f[p + 2 * q]
                );
            }
        }
    }
}
