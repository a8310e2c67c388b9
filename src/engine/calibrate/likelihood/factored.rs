//! The structured covariance factorized at one point, for solves: what the
//! summaries need (predictions of δ, quadratic forms), not the sampler.

use super::structured_model::{self as model_term, add_transposed_product, SmallLu};
use crate::engine::gp::CholeskyWorkspace;

/// `M = I + Wᵀ W` (Cholesky) without a model term; `I + H C` (LU) with one.
pub(super) enum Capacitance {
    Cholesky(CholeskyWorkspace),
    General { lu: SmallLu, s: Vec<f64>, data_rank: usize },
}

/// Σ = blockdiag(L_b L_bᵀ) + U C Uᵀ factorized (`Structure::factor_at`).
pub struct Factored {
    pub(super) blocks: Vec<CholeskyWorkspace>,
    pub(super) w_rows: Vec<Vec<f64>>,
    pub(super) capacitance: Capacitance,
    pub(super) rank: usize,
}

impl Factored {
    /// `Σ⁻¹ r` in place (all points, block order): `L⁻ᵀ (z − W C (I + H C)⁻¹ Wᵀ z)`,
    /// z = L⁻¹ r (C = I without a model term: `(I + Wᵀ W)⁻¹`).
    pub fn solve_in_place(&self, r: &mut [f64]) {
        let mut c = vec![0.0; self.rank];
        let mut at = 0;
        for (chol, w) in self.blocks.iter().zip(&self.w_rows) {
            let nb = chol.n();
            chol.solve_lower_in_place(&mut r[at..at + nb]);
            add_transposed_product(w, nb, self.rank, &r[at..at + nb], &mut c);
            at += nb;
        }
        if self.rank > 0 {
            match &self.capacitance {
                Capacitance::Cholesky(chol) => chol.solve_in_place(&mut c),
                Capacitance::General { lu, s, data_rank } => {
                    lu.solve_in_place(&mut c);
                    let y = c.clone();
                    model_term::weighted(s, *data_rank, &y, &mut c);
                }
            }
        }
        let mut at = 0;
        for (chol, w) in self.blocks.iter().zip(&self.w_rows) {
            let nb = chol.n();
            let z = &mut r[at..at + nb];
            for (p, cp) in c.iter().enumerate() {
                z.iter_mut().zip(&w[p * nb..(p + 1) * nb]).for_each(|(zi, wi)| *zi -= wi * cp);
            }
            chol.solve_upper_in_place(z);
            at += nb;
        }
    }

    /// `kᵀ Σ⁻¹ k` for a vector nonzero only on block b's points (`k_b`,
    /// overwritten): `‖L_b⁻¹ k_b‖² − aᵀ C (I + H C)⁻¹ a`, `a = W_bᵀ L_b⁻¹ k_b`.
    pub fn block_quadratic(&self, b: usize, k_b: &mut [f64]) -> f64 {
        let chol = &self.blocks[b];
        chol.solve_lower_in_place(k_b);
        let mut quad: f64 = k_b.iter().map(|v| v * v).sum();
        if self.rank > 0 {
            let mut c = vec![0.0; self.rank];
            add_transposed_product(&self.w_rows[b], chol.n(), self.rank, k_b, &mut c);
            match &self.capacitance {
                Capacitance::Cholesky(m) => {
                    m.solve_lower_in_place(&mut c);
                    quad -= c.iter().map(|v| v * v).sum::<f64>();
                }
                Capacitance::General { lu, s, data_rank } => {
                    let mut y = c.clone();
                    lu.solve_in_place(&mut y);
                    quad -= model_term::weighted_dot(&c, s, *data_rank, &y);
                }
            }
        }
        quad
    }
}
