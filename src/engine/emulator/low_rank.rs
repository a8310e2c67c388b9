//! An emulator's predictive covariance at a set of its outputs in the form
//! the structured likelihood uses (`LowRankModelCovariance`): its kept
//! components are N × K loadings whose weights change with θ, the dropped
//! ones are fixed columns, and the noise the runs leave in the PCA,
//! `c P N P` with `P = I − U Uᵀ` (U the kept loadings), is
//! `c N − c U (N U)ᵀ − c (N U) Uᵀ + c U (Uᵀ N U) Uᵀ`: the runs' noise N
//! inside each block of points plus columns `[U, N U]` with the indefinite
//! weights `c [[Uᵀ N U, −I], [−I, 0]]`. Together the rank is the dropped
//! components' count plus K (2K with run noise), whatever the number of
//! outputs.

use super::run_noise::{output_noise_cov, pca_noise_signal_weight};
use super::Emulator;
use crate::engine::model::LowRankModelCovariance;

impl Emulator {
    /// The covariance of [`Emulator::add_points_covariance`] at outputs
    /// `idx` (block b's points at `offsets[b]..offsets[b + 1]`), before the
    /// per-point factors. `None` when the runs' noise is correlated between
    /// outputs of two blocks: the noise left in the PCA then has no such form.
    pub fn low_rank_covariance(&self, idx: &[usize], offsets: &[usize]) -> Option<LowRankModelCovariance> {
        let (n, m, kept) = (idx.len(), self.n_outputs(), self.n_components());
        let basis = |k: usize| &self.parts.basis[k * m..(k + 1) * m];
        let noise = output_noise_cov(&self.parts);
        let noisy = noise.iter().any(|v| *v != 0.0);
        let block_of: Vec<usize> =
            offsets.windows(2).enumerate().flat_map(|(b, w)| std::iter::repeat_n(b, w[1] - w[0])).collect();
        if block_of.len() != n {
            return None;
        }
        if noisy {
            for j in 0..n {
                for i in (0..n).filter(|&i| block_of[i] != block_of[j]) {
                    if noise[idx[i] * m + idx[j]] != 0.0 {
                        return None;
                    }
                }
            }
        }
        let runs = self.parts.design_ids.len().max(1) as f64;
        let c = if noisy { (1.0 + pca_noise_signal_weight(&self.parts, &noise)) / runs } else { 0.0 };
        let blocks = offsets
            .windows(2)
            .map(|w| {
                let (at, noise) = (&idx[w[0]..w[1]], &noise);
                at.iter().flat_map(|&b| at.iter().map(move |&a| c * noise[a * m + b])).collect()
            })
            .collect();
        let dropped: Vec<(usize, f64)> =
            self.dropped_weights.iter().enumerate().filter(|(_, t)| **t > 0.0).map(|(j, t)| (kept + j, *t)).collect();
        let u0 = dropped.len();
        let p = u0 + kept + if noisy { kept } else { 0 };
        let mut columns = vec![0.0; n * p];
        let mut weights = vec![0.0; p * p];
        let mut set_column = |col: usize, values: &[f64]| {
            for (i, &o) in idx.iter().enumerate() {
                columns[i + col * n] = values[o];
            }
        };
        for (col, &(k, t)) in dropped.iter().enumerate() {
            set_column(col, basis(k));
            weights[col + col * p] = t;
        }
        for k in 0..kept {
            set_column(u0 + k, basis(k));
        }
        if noisy {
            let nu0 = u0 + kept;
            for k in 0..kept {
                let nu: Vec<f64> = (0..m).map(|a| dot(&noise[a * m..(a + 1) * m], basis(k))).collect();
                set_column(nu0 + k, &nu);
                for l in 0..kept {
                    weights[(u0 + l) + (u0 + k) * p] = c * dot(basis(l), &nu);
                }
                weights[(u0 + k) + (nu0 + k) * p] = -c;
                weights[(nu0 + k) + (u0 + k) * p] = -c;
            }
        }
        Some(LowRankModelCovariance { blocks, columns, weights, weighted: (u0..u0 + kept).collect() })
    }

    /// The weights of the kept components at θ, from their predicted
    /// variances: `w_k = var_k σ_k²`.
    pub fn component_weights(&self, comp_var: &[f64], w: &mut [f64]) {
        for ((w, v), sd) in w.iter_mut().zip(comp_var).zip(&self.component_sd) {
            *w = v * sd * sd;
        }
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}
