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
//! `det(I + H C) = det Σ / det B` must come out positive.

use super::structured::{add_gram, add_transposed_product, Scratch, Structure};
use crate::engine::gp::CholeskyWorkspace;
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
    h: Vec<f64>,
    s: Vec<f64>,
    lu: SmallLu,
    a: Vec<f64>,
    y: Vec<f64>,
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

impl Structure {
    /// Whether an evaluation costs fewer operations than the dense
    /// factorization of the same covariance: the low-rank term's rank R
    /// against N (triangular solves N n_b R, its Gram matrix N R², the LU
    /// R³, against N³/3 and the N² K of filling an emulator's covariance).
    /// An emulator trained on many runs and predicting few points is
    /// cheaper dense.
    pub fn cheaper_than_dense(&self) -> bool {
        let n: usize = self.sizes.iter().sum();
        let (n, r) = (n as f64, (self.rank + self.model.as_ref().map_or(0, |m| m.rank)) as f64);
        let nb = self.sizes.iter().copied().max().unwrap_or(0) as f64;
        let k = self.model.as_ref().map_or(0, |m| m.weighted.len()) as f64;
        n * nb * r + n * r * r + r * r * r < n * n * n / 3.0 + n * n * k
    }

    /// Block b's rows of `U = [V, G F]` into `w` (column-major n_b × R).
    pub(super) fn fill_u_rows(&self, model: &ModelTerm, b: usize, nb: usize, g: &[f64], w: &mut [f64]) {
        let data = nb * self.rank;
        w[..data].copy_from_slice(&self.v_rows[b]);
        for (dst, src) in w[data..data + nb * model.rank].chunks_mut(nb).zip(model.f_rows[b].chunks(nb)) {
            for ((d, s), gi) in dst.iter_mut().zip(src).zip(g) {
                *d = gi * s;
            }
        }
    }

    /// `log N(r | 0, Σ)` with the model's term (see the module docs), each
    /// block's δ from `fill_block`; `scratch.model`'s `g` and weights must
    /// hold θ's. Returns the log-density and the largest jitter used.
    pub fn log_pdf_with_model(
        &self,
        model: &ModelTerm,
        resid: &mut [f64],
        scratch: &mut Scratch,
        chols: &mut [CholeskyWorkspace],
        mut fill_block: impl FnMut(usize, &mut [f64]),
    ) -> Option<(f64, f64)> {
        let (rd, r) = (self.rank, self.rank + model.rank);
        let Scratch { w, model: ms, .. } = scratch;
        let ms = ms.as_mut().expect("a structure with a model term has its scratch");
        ms.h.iter_mut().for_each(|v| *v = 0.0);
        ms.a.iter_mut().for_each(|v| *v = 0.0);
        let (mut quad, mut log_det, mut jitter) = (0.0, 0.0, 0.0f64);
        let mut at = 0;
        for (b, own) in self.block_data.iter().enumerate() {
            let chol = &mut chols[b];
            let nb = chol.n();
            let g = &ms.g[at..at + nb];
            let d = &model.blocks[b];
            let mut refill = |lower: &mut [f64]| {
                fill_block(b, lower);
                for j in 0..nb {
                    for i in j..nb {
                        lower[i + j * nb] += own[i + j * nb] + g[i] * g[j] * d[i + j * nb];
                    }
                }
            };
            refill(&mut chol.factor);
            jitter = jitter.max(chol.factorize_refilling(&mut refill).ok()?);
            log_det += chol.log_det();
            let z = &mut resid[at..at + nb];
            chol.solve_lower_in_place(z);
            quad += z.iter().map(|v| v * v).sum::<f64>();
            let wb = &mut w[..nb * r];
            self.fill_u_rows(model, b, nb, g, wb);
            chol.solve_lower_columns_in_place(wb, r);
            add_gram(wb, nb, r, &mut ms.h);
            add_transposed_product(wb, nb, r, z, &mut ms.a);
            at += nb;
        }
        model.weights_at(&ms.theta_weights, &mut ms.s);
        let capacitance = capacitance_matrix(&mut ms.h, &ms.s, rd, r, &mut ms.lu.m);
        let log_det_m = capacitance.then(|| ms.lu.factorize()).flatten()?;
        ms.y.copy_from_slice(&ms.a);
        ms.lu.solve_in_place(&mut ms.y);
        quad -= weighted_dot(&ms.a, &ms.s, rd, &ms.y);
        log_det += log_det_m;
        Some((-0.5 * (quad + log_det + resid.len() as f64 * super::structured::LN_2PI), jitter))
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
