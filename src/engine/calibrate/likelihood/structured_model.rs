//! A model's covariance across observables inside the structured likelihood.
//!
//! With a model whose covariance links the observables (an emulator's, see
//! `LowRankModelCovariance`) the joint covariance is
//!
//! `Σ = blockdiag(B_b) + V Vᵀ + (G F) S(θ) (G F)ᵀ`,
//!
//! `B_b` holding δ, the data's remainder and `G_b D_b G_b`. With
//! `U = [V, G F]` and `C = blockdiag(I, S)` (S need not be positive: the
//! noise left in an emulator's PCA enters with negative weights), Woodbury's
//! identity in the form that never inverts C and the determinant lemma give
//!
//! `rᵀ Σ⁻¹ r = ‖z‖² − aᵀ C (I + H C)⁻¹ a`, `det Σ = det B · det(I + H C)`,
//!
//! with `z = L⁻¹ r`, `W = L⁻¹ U`, `H = Wᵀ W` and `a = Wᵀ z`. `I + H C` is
//! not symmetric; a small LU with partial pivoting factorizes it, and
//! `det(I + H C) = det Σ / det B` must come out positive. This module holds
//! the term, its buffers and the small algebra; `Structure::log_pdf_with_model`
//! (`structured`) evaluates it.

use crate::engine::model::LowRankModelCovariance;

/// The model's part of the structure: `F`'s rows per block, `S`, `D_b`.
#[derive(Clone)]
pub struct ModelTerm {
    /// Block b's rows of `F` (column-major n_b × p).
    pub f_rows: Vec<Vec<f64>>,
    /// `S` without the θ weights (column-major p × p).
    pub weights: Vec<f64>,
    /// The columns whose diagonal entry of `S` gets the θ weights.
    pub weighted: Vec<usize>,
    /// `D_b` per block (full, column-major).
    pub blocks: Vec<Vec<f64>>,
    pub rank: usize,
}

impl ModelTerm {
    /// Split by the joint layout's blocks (`offsets`, N + 1 entries).
    pub fn new(model: LowRankModelCovariance, offsets: &[usize]) -> ModelTerm {
        let (n, rank) = (*offsets.last().unwrap_or(&0), model.rank());
        let f_rows = offsets
            .windows(2)
            .map(|w| (0..rank).flat_map(|k| model.columns[k * n + w[0]..k * n + w[1]].iter().copied()).collect())
            .collect();
        ModelTerm { f_rows, weights: model.weights, weighted: model.weighted, blocks: model.blocks, rank }
    }

    /// `S(θ)` into `s` (p × p).
    pub(super) fn weights_at(&self, theta_weights: &[f64], s: &mut [f64]) {
        s.copy_from_slice(&self.weights);
        for (&col, w) in self.weighted.iter().zip(theta_weights) {
            s[col + col * self.rank] += w;
        }
    }
}

/// The per-evaluation buffers of the model term.
pub struct ModelScratch {
    /// `G`'s diagonal (N) and the θ weights (K), filled by the caller.
    pub g: Vec<f64>,
    pub theta_weights: Vec<f64>,
    pub(super) h: Vec<f64>,
    pub(super) s: Vec<f64>,
    pub(super) lu: SmallLu,
    pub(super) a: Vec<f64>,
    pub(super) y: Vec<f64>,
}

impl ModelScratch {
    pub fn new(n: usize, data_rank: usize, model: &ModelTerm) -> Self {
        let r = data_rank + model.rank;
        ModelScratch {
            g: vec![0.0; n],
            theta_weights: vec![0.0; model.weighted.len()],
            h: vec![0.0; r * r],
            s: vec![0.0; model.rank * model.rank],
            lu: SmallLu::new(r),
            a: vec![0.0; r],
            y: vec![0.0; r],
        }
    }
}

/// `M = I + H C` into `m` (column-major R × R) from `H`'s lower triangle
/// (mirrored here), C = blockdiag(I_rd, S). False if H is not finite.
pub(super) fn capacitance_matrix(h: &mut [f64], s: &[f64], rd: usize, r: usize, m: &mut [f64]) -> bool {
    for j in 0..r {
        for i in j + 1..r {
            h[j + i * r] = h[i + j * r];
        }
    }
    if !h.iter().all(|v| v.is_finite()) {
        return false;
    }
    let p = r - rd;
    for j in 0..r {
        for i in 0..r {
            m[i + j * r] =
                if j < rd { h[i + j * r] } else { (0..p).map(|l| h[i + (rd + l) * r] * s[l + (j - rd) * p]).sum() };
        }
        m[j + j * r] += 1.0;
    }
    true
}

/// `aᵀ C y`, C = blockdiag(I_rd, S).
pub(super) fn weighted_dot(a: &[f64], s: &[f64], rd: usize, y: &[f64]) -> f64 {
    let p = a.len() - rd;
    let data: f64 = a[..rd].iter().zip(&y[..rd]).map(|(u, v)| u * v).sum();
    let model: f64 = (0..p).map(|l| a[rd + l] * (0..p).map(|q| s[l + q * p] * y[rd + q]).sum::<f64>()).sum();
    data + model
}

/// `C y` into `out`, C = blockdiag(I_rd, S).
pub(super) fn weighted(s: &[f64], rd: usize, y: &[f64], out: &mut [f64]) {
    let p = y.len() - rd;
    out[..rd].copy_from_slice(&y[..rd]);
    for l in 0..p {
        out[rd + l] = (0..p).map(|q| s[l + q * p] * y[rd + q]).sum();
    }
}

/// LU with partial pivoting of a small general matrix, in place (no
/// allocation after `new`: it runs at every evaluation).
#[derive(Clone)]
pub struct SmallLu {
    n: usize,
    pub m: Vec<f64>,
    piv: Vec<usize>,
}

impl SmallLu {
    pub fn new(n: usize) -> Self {
        SmallLu { n, m: vec![0.0; n * n], piv: vec![0; n] }
    }

    /// Factorizes `m`; returns ln det, or `None` when the determinant is not
    /// positive (Σ would not be positive definite) or the matrix is singular.
    pub fn factorize(&mut self) -> Option<f64> {
        let (n, m) = (self.n, &mut self.m);
        let (mut log_det, mut negative) = (0.0, false);
        for k in 0..n {
            let p = (k..n).max_by(|&a, &b| m[a + k * n].abs().total_cmp(&m[b + k * n].abs()))?;
            self.piv[k] = p;
            if p != k {
                negative = !negative;
                for j in 0..n {
                    m.swap(k + j * n, p + j * n);
                }
            }
            let pivot = m[k + k * n];
            if pivot == 0.0 || !pivot.is_finite() {
                return None;
            }
            negative ^= pivot < 0.0;
            log_det += pivot.abs().ln();
            for i in k + 1..n {
                m[i + k * n] /= pivot;
            }
            for j in k + 1..n {
                let mkj = m[k + j * n];
                if mkj != 0.0 {
                    for i in k + 1..n {
                        m[i + j * n] -= m[i + k * n] * mkj;
                    }
                }
            }
        }
        (!negative).then_some(log_det)
    }

    /// `b ← M⁻¹ b` from the factors.
    pub fn solve_in_place(&self, b: &mut [f64]) {
        let (n, m) = (self.n, &self.m);
        for k in 0..n {
            b.swap(k, self.piv[k]);
        }
        for j in 0..n {
            let bj = b[j];
            for i in j + 1..n {
                b[i] -= m[i + j * n] * bj;
            }
        }
        for j in (0..n).rev() {
            b[j] /= m[j + j * n];
            let bj = b[j];
            for i in 0..j {
                b[i] -= m[i + j * n] * bj;
            }
        }
    }
}

/// `lower += Wᵀ W` (lower triangle of r × r), W column-major n × r.
pub(super) fn add_gram(w: &[f64], n: usize, r: usize, lower: &mut [f64]) {
    for q in 0..r {
        let wq = &w[q * n..(q + 1) * n];
        for p in q..r {
            let wp = &w[p * n..(p + 1) * n];
            lower[p + q * r] += wp.iter().zip(wq).map(|(a, b)| a * b).sum::<f64>();
        }
    }
}

/// `c += Wᵀ z`, W column-major n × r.
pub(super) fn add_transposed_product(w: &[f64], n: usize, r: usize, z: &[f64], c: &mut [f64]) {
    for (p, cp) in c.iter_mut().enumerate().take(r) {
        *cp += w[p * n..(p + 1) * n].iter().zip(z).map(|(a, b)| a * b).sum::<f64>();
    }
}
