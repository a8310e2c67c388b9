//! Fisher information and Cramér–Rao bounds of θ for the model without MD:
//! the smallest spread any unbiased analysis of the data can reach, which
//! `diagnose` sets beside the posterior's.

use super::block::ObservableBlock;
use super::likelihood::MdLikelihood;
use crate::engine::gp::CholeskyWorkspace;

impl MdLikelihood {
    /// Fisher information of θ for the model without MD at `theta`,
    /// `F = Jᵀ C⁻¹ J` (column-major d × d) with C the data's covariance (per
    /// block, or joint), in standardized units (the scales cancel), with the
    /// Jacobian by central differences of step `steps[k]` in θ_k. `None` when
    /// the model carries its own θ-dependent covariance (an emulator): that
    /// dependence carries information this form leaves out, so it would be no bound.
    pub fn fisher_information(&self, theta: &[f64], steps: &[f64]) -> Option<Vec<f64>> {
        if self.model_covariance {
            return None;
        }
        let d = self.n_theta;
        let jacobians: Vec<Vec<f64>> =
            self.blocks.iter().map(|b| self.standardized_jacobian(b, theta, steps)).collect();
        let whitened: Vec<(Vec<f64>, usize)> = match &self.joint {
            Some(joint) => {
                let n = joint.len();
                let mut whole = vec![0.0; n * d];
                for (b, jac) in jacobians.iter().enumerate() {
                    let nb = self.blocks[b].len();
                    for k in 0..d {
                        whole[k * n + joint.offsets[b]..k * n + joint.offsets[b] + nb]
                            .copy_from_slice(&jac[k * nb..(k + 1) * nb]);
                    }
                }
                vec![(whiten(joint.data.clone(), n, whole, d)?, n)]
            }
            None => {
                let mut out = Vec::new();
                for (block, jac) in self.blocks.iter().zip(jacobians) {
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
    fn standardized_jacobian(&self, block: &ObservableBlock, theta: &[f64], steps: &[f64]) -> Vec<f64> {
        let (n, d) = (block.len(), self.n_theta);
        let (mut up, mut down) = (vec![0.0; n], vec![0.0; n]);
        let mut jac = vec![0.0; n * d];
        let mut shifted = theta.to_vec();
        for k in 0..d {
            shifted[k] = theta[k] + steps[k];
            self.simulator.predict(block.model_index, &block.x, &shifted, &mut up);
            shifted[k] = theta[k] - steps[k];
            self.simulator.predict(block.model_index, &block.x, &shifted, &mut down);
            shifted[k] = theta[k];
            for i in 0..n {
                jac[i + k * n] = (up[i] - down[i]) / (2.0 * steps[k] * block.scale);
            }
        }
        jac
    }

    /// Cramér–Rao standard deviations of θ at `theta`: the smallest spread any
    /// unbiased analysis of these data can reach with this model, `sqrt(diag F⁻¹)`.
    /// `None` as for `fisher_information`, or when F is singular (parameters
    /// the data cannot tell apart, such as g and a constant extra force).
    pub fn cramer_rao_sd(&self, theta: &[f64], steps: &[f64]) -> Option<Vec<f64>> {
        let d = self.n_theta;
        let fisher = self.fisher_information(theta, steps)?;
        let mut chol = CholeskyWorkspace::new(d);
        chol.factor.copy_from_slice(&fisher);
        if !chol.factorize_exact() {
            return None;
        }
        let inv = chol.inverse();
        let sd: Vec<f64> = (0..d).map(|k| inv[k + k * d].sqrt()).collect();
        sd.iter().all(|v| v.is_finite()).then_some(sd)
    }
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
