//! The emulator's belief about the simulator's *mean* output, without the
//! run-to-run noise: what more design points can reduce, and what adaptive
//! design (`engine::refine`) works on.
//!
//! Each kept component's score is a GP; at points `C` its latent posterior
//! covariance is `K_CC − K_CXᵀ K_XX⁻¹ K_XC` (kernel without the white-noise
//! term at C; Rasmussen & Williams eq. 2.24). A new run at `a` conditions it
//! as a noisy observation, a rank-one downdate:
//! `Σ ← Σ − Σ[:,a] Σ[a,:] / (Σ[a,a] + σ_n²)`.

use super::Emulator;
use crate::engine::gp::scaled_sq_dist;

/// The kept components' latent posterior at a set of points.
#[derive(Clone, Debug)]
pub struct LatentPosterior {
    /// Number of points.
    pub points: usize,
    /// Component means, row-major points × K.
    pub means: Vec<f64>,
    /// Per component, the covariance among the points (column-major B × B).
    pub covs: Vec<Vec<f64>>,
    /// Per component, the run noise variance σ_n² (whitened score units).
    pub noise: Vec<f64>,
}

impl LatentPosterior {
    /// Latent variance of component `c` at point `b`.
    pub fn var(&self, c: usize, b: usize) -> f64 {
        self.covs[c][b * self.points + b].max(0.0)
    }

    /// Conditions every component on one more run at point `a` (noise
    /// included): the GP with that run added, hyperparameters unchanged. The
    /// variances do not depend on what the run returns.
    pub fn condition_on_run_at(&mut self, a: usize) {
        let n = self.points;
        for (cov, &noise) in self.covs.iter_mut().zip(&self.noise) {
            let col: Vec<f64> = cov[a * n..(a + 1) * n].to_vec();
            let denom = col[a].max(0.0) + noise;
            if denom <= 0.0 {
                continue;
            }
            for j in 0..n {
                let f = col[j] / denom;
                if f == 0.0 {
                    continue;
                }
                for i in 0..n {
                    cov[j * n + i] -= f * col[i];
                }
            }
        }
    }
}

impl Emulator {
    /// Latent posterior of every kept component at `thetas` (row-major B × d).
    pub fn latent_posterior(&self, thetas: &[f64]) -> LatentPosterior {
        let d = self.n_parameters();
        let n = self.parts.design_ids.len();
        let kc = self.n_components();
        let unit = self.unit_rows(thetas);
        let b = unit.len() / d.max(1);
        let mut means = vec![0.0; b * kc];
        let mut covs = Vec::with_capacity(kc);
        let mut kstar = vec![0.0; n * b];
        for (c, gp) in self.gps.iter().enumerate() {
            let kern = |r2: f64| gp.signal_var * self.parts.kernel.corr(r2) + gp.constant;
            self.cross_kernel(gp, &unit, &mut kstar, |q, mean| means[q * kc + c] = mean);
            // W = L⁻¹ K_XC; the covariance is K_CC − WᵀW.
            let l = faer::MatRef::from_column_major_slice(&gp.factor, n, n);
            faer::linalg::triangular_solve::solve_lower_triangular_in_place(
                l,
                faer::MatMut::from_column_major_slice_mut(&mut kstar, n, b),
                faer::Par::Seq,
            );
            let w = faer::MatRef::from_column_major_slice(&kstar, n, b);
            let mut cov = vec![0.0; b * b];
            let cm = faer::MatMut::from_column_major_slice_mut(&mut cov, b, b);
            faer::linalg::matmul::matmul(cm, faer::Accum::Replace, w.transpose(), w, -1.0, faer::Par::Seq);
            for j in 0..b {
                for i in 0..b {
                    cov[j * b + i] +=
                        kern(scaled_sq_dist(&unit[i * d..(i + 1) * d], &unit[j * d..(j + 1) * d], &gp.inv_l2));
                }
            }
            covs.push(cov);
        }
        LatentPosterior { points: b, means, covs, noise: self.gps.iter().map(|g| g.noise_var).collect() }
    }

    /// Variance of output `j` in observable units from component variances,
    /// without the truncated components (which more runs do not reduce).
    pub fn output_var_from_component_vars(&self, comp_var: &[f64], j: usize, jac: f64) -> f64 {
        let m = self.n_outputs();
        let v: f64 = comp_var
            .iter()
            .enumerate()
            .map(|(k, v)| v * (self.component_sd[k] * self.parts.basis[k * m + j]).powi(2))
            .sum();
        v * jac * jac
    }
}
