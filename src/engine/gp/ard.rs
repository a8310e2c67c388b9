//! Stationary ARD kernels of the emulators' Gaussian processes and their log
//! marginal likelihood with its analytic gradient.

use super::cholesky::{CholeskyWorkspace, NotPositiveDefinite};

/// Stationary ARD correlation functions used by the emulators, written in
/// terms of the scaled squared distance `r² = Σ_k (a_k-b_k)²/ℓ_k²`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ArdKernel {
    /// `exp(-r²/2)`
    SquaredExponential,
    /// `(1 + √5 r + 5r²/3) exp(-√5 r)`
    Matern52,
}

impl ArdKernel {
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "se" | "squared_exponential" | "rbf" => Some(ArdKernel::SquaredExponential),
            "matern52" | "matern_5_2" => Some(ArdKernel::Matern52),
            _ => None,
        }
    }

    #[inline]
    pub fn corr(self, r2: f64) -> f64 {
        match self {
            ArdKernel::SquaredExponential => (-0.5 * r2).exp(),
            ArdKernel::Matern52 => {
                let r = (5.0 * r2).sqrt();
                (1.0 + r + r * r / 3.0) * (-r).exp()
            }
        }
    }

    /// `d corr / d r²`, finite at r = 0 for both kernels.
    #[inline]
    pub fn dcorr_dr2(self, r2: f64) -> f64 {
        match self {
            ArdKernel::SquaredExponential => -0.5 * (-0.5 * r2).exp(),
            ArdKernel::Matern52 => {
                let r = (5.0 * r2).sqrt();
                -(5.0 / 6.0) * (1.0 + r) * (-r).exp()
            }
        }
    }

    /// `corr` of every value of `r2`, in place: four at a time with `wide`'s
    /// vector exponential (already built, through nalgebra), within 1 ulp of
    /// libm's (mean 0.08 ulp over [−20, 0]) and without its calls; an emulator's cross
    /// kernel is one exponential per design point and component per θ, a
    /// sixth of a heavy-ion calibration when it called libm. Every value,
    /// the last ones too, goes through the same vector code, so the
    /// correlation of a point does not depend on its place in the slice.
    pub fn corr_in_place(self, r2: &mut [f64]) {
        let mut chunks = r2.chunks_exact_mut(4);
        for chunk in &mut chunks {
            let out = self.corr4(wide::f64x4::new([chunk[0], chunk[1], chunk[2], chunk[3]]));
            chunk.copy_from_slice(&out.to_array());
        }
        let tail = chunks.into_remainder();
        if !tail.is_empty() {
            let mut padded = [0.0; 4];
            padded[..tail.len()].copy_from_slice(tail);
            let out = self.corr4(wide::f64x4::new(padded)).to_array();
            tail.copy_from_slice(&out[..tail.len()]);
        }
    }

    #[inline(always)]
    fn corr4(self, r2: wide::f64x4) -> wide::f64x4 {
        match self {
            // `wide`'s exp gives 0 for NaN: keep a NaN distance NaN, as libm's
            // would, so that a NaN θ cannot predict a finite value.
            ArdKernel::SquaredExponential => r2.is_nan().blend(r2, (r2 * wide::f64x4::splat(-0.5)).exp()),
            ArdKernel::Matern52 => {
                let r = (r2 * wide::f64x4::splat(5.0)).sqrt();
                (wide::f64x4::ONE + r + r * r / wide::f64x4::splat(3.0)) * (-r).exp()
            }
        }
    }

    /// `corr` and `d corr / d r²` together (one exponential).
    #[inline]
    pub fn corr_and_derivative(self, r2: f64) -> (f64, f64) {
        match self {
            ArdKernel::SquaredExponential => {
                let e = (-0.5 * r2).exp();
                (e, -0.5 * e)
            }
            ArdKernel::Matern52 => {
                let r = (5.0 * r2).sqrt();
                let e = (-r).exp();
                ((1.0 + r + r * r / 3.0) * e, -(5.0 / 6.0) * (1.0 + r) * e)
            }
        }
    }
}

/// `Σ_k (a_k-b_k)² / ℓ_k²` given `inv_l2[k] = 1/ℓ_k²`.
#[inline]
pub fn scaled_sq_dist(a: &[f64], b: &[f64], inv_l2: &[f64]) -> f64 {
    let mut q = 0.0;
    for k in 0..a.len() {
        let d = a[k] - b[k];
        q += d * d * inv_l2[k];
    }
    q
}

/// Hyperparameters of an emulator GP, `k(a,b) = σ_f² corr(r²) + c + σ_n² [a=b]`,
/// stored as logs so that an unconstrained optimizer can move them:
/// `[ln σ_f², ln ℓ_1 … ln ℓ_d, ln c, ln σ_n²]`.
#[derive(Clone, Debug, PartialEq)]
pub struct ArdHyper {
    pub log_params: Vec<f64>,
}

impl ArdHyper {
    pub fn n_params(d: usize) -> usize {
        d + 3
    }
    pub fn names(d: usize) -> Vec<String> {
        let mut v = vec!["log_signal_var".to_string()];
        v.extend((0..d).map(|k| format!("log_length_{k}")));
        v.push("log_constant".into());
        v.push("log_noise_var".into());
        v
    }
    pub fn dim(&self) -> usize {
        self.log_params.len() - 3
    }
    pub fn signal_var(&self) -> f64 {
        self.log_params[0].exp()
    }
    pub fn inv_sq_lengths(&self) -> Vec<f64> {
        self.log_params[1..1 + self.dim()].iter().map(|l| (-2.0 * l).exp()).collect()
    }
    pub fn constant(&self) -> f64 {
        self.log_params[self.dim() + 1].exp()
    }
    pub fn noise_var(&self) -> f64 {
        self.log_params[self.dim() + 2].exp()
    }
}

/// Fills the lower triangle of `K` (column-major, n×n) for row-major inputs `x` (n×d).
pub fn ard_gram_lower(kernel: ArdKernel, hyper: &ArdHyper, x: &[f64], n: usize, out: &mut [f64]) {
    let d = hyper.dim();
    let (sf2, c, sn2) = (hyper.signal_var(), hyper.constant(), hyper.noise_var());
    let inv_l2 = hyper.inv_sq_lengths();
    for j in 0..n {
        let xj = &x[j * d..(j + 1) * d];
        out[j + j * n] = sf2 + c + sn2;
        for i in j + 1..n {
            let r2 = scaled_sq_dist(&x[i * d..(i + 1) * d], xj, &inv_l2);
            out[i + j * n] = sf2 * kernel.corr(r2) + c;
        }
    }
}

/// Log marginal likelihood `log N(y | 0, K)` of a GP with ARD kernel and, if
/// `gradient` is given, its gradient with respect to `hyper.log_params`:
/// `∂/∂θ_j = ½ tr((ααᵀ - K⁻¹) ∂K/∂θ_j)`, `α = K⁻¹y` (Rasmussen & Williams eq. 5.9).
pub fn ard_log_marginal_likelihood(
    kernel: ArdKernel,
    hyper: &ArdHyper,
    x: &[f64],
    y: &[f64],
    gradient: Option<&mut [f64]>,
) -> Result<f64, NotPositiveDefinite> {
    let n = y.len();
    let d = hyper.dim();
    let (sf2, c, sn2) = (hyper.signal_var(), hyper.constant(), hyper.noise_var());
    let inv_l2 = hyper.inv_sq_lengths();
    // One pass over pairs fills K and keeps d corr/d r² for the gradient.
    let mut chol = CholeskyWorkspace::new(n);
    let mut pair_corr = if gradient.is_some() { vec![(0.0, 0.0); n * n] } else { Vec::new() };
    for j in 0..n {
        let xj = &x[j * d..(j + 1) * d];
        chol.factor[j + j * n] = sf2 + c + sn2;
        for i in j + 1..n {
            let r2 = scaled_sq_dist(&x[i * d..(i + 1) * d], xj, &inv_l2);
            let (corr, dc) = kernel.corr_and_derivative(r2);
            chol.factor[i + j * n] = sf2 * corr + c;
            if !pair_corr.is_empty() {
                pair_corr[i + j * n] = (corr, dc);
            }
        }
    }
    chol.factorize()?;
    let mut alpha = y.to_vec();
    chol.solve_in_place(&mut alpha);
    let quad: f64 = alpha.iter().zip(y).map(|(a, b)| a * b).sum();
    let lml = -0.5 * (quad + chol.log_det() + n as f64 * (2.0 * std::f64::consts::PI).ln());
    let Some(grad) = gradient else {
        return Ok(lml);
    };
    // W = ααᵀ - K⁻¹, lower triangle used.
    let kinv = chol.inverse();
    grad.iter_mut().for_each(|g| *g = 0.0);
    let mut dl = vec![0.0; d];
    let (mut g_sf, mut g_c, mut g_n) = (0.0, 0.0, 0.0);
    for j in 0..n {
        let xj = &x[j * d..(j + 1) * d];
        // Diagonal: r = 0, so only σ_f², c and σ_n² contribute.
        let wjj = alpha[j] * alpha[j] - kinv[j + j * n];
        g_sf += 0.5 * wjj * sf2;
        g_c += 0.5 * wjj * c;
        g_n += 0.5 * wjj * sn2;
        for i in j + 1..n {
            let xi = &x[i * d..(i + 1) * d];
            // Off-diagonal pairs appear twice in the trace.
            let w = alpha[i] * alpha[j] - kinv[i + j * n];
            let (corr, dcorr) = pair_corr[i + j * n];
            g_sf += w * sf2 * corr;
            g_c += w * c;
            // ∂r²/∂ln ℓ_k = -2 Δ_k²/ℓ_k².
            let f = w * sf2 * dcorr * -2.0;
            for k in 0..d {
                let dk = xi[k] - xj[k];
                dl[k] += f * dk * dk * inv_l2[k];
            }
        }
    }
    grad[0] = g_sf;
    grad[1..1 + d].copy_from_slice(&dl);
    grad[1 + d] = g_c;
    grad[2 + d] = g_n;
    Ok(lml)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The vector correlations are libm's to a few ulps, over lengths that
    /// leave every tail size, at distances from 0 to where they underflow.
    #[test]
    fn vector_correlations_equal_the_scalar_ones() {
        for kernel in [ArdKernel::Matern52, ArdKernel::SquaredExponential] {
            for len in [1usize, 2, 3, 4, 5, 7, 8, 161] {
                let r2: Vec<f64> =
                    (0..len).map(|i| if i == 0 { 0.0 } else { 1e-12 * 1.7f64.powi(i as i32 % 70) }).collect();
                let mut vector = r2.clone();
                kernel.corr_in_place(&mut vector);
                for (&q, &v) in r2.iter().zip(&vector) {
                    let scalar = kernel.corr(q);
                    assert!((v - scalar).abs() <= 8.0 * f64::EPSILON * scalar, "{kernel:?}, r² = {q}: {v} vs {scalar}");
                }
            }
            let mut nan = [f64::NAN, 0.5];
            kernel.corr_in_place(&mut nan);
            let beside = (nan[1] - kernel.corr(0.5)).abs() <= 8.0 * f64::EPSILON;
            assert!(nan[0].is_nan() && beside, "{kernel:?}: a NaN distance gives {nan:?}");
            // Far apart, down to where exp(−r) underflows, as the scalar one.
            let far = [700.0, 2e3, 5e4, 1e6, 1e300];
            let mut vector = far;
            kernel.corr_in_place(&mut vector);
            for (&q, &v) in far.iter().zip(&vector) {
                let scalar = kernel.corr(q);
                let close = (v - scalar).abs() <= 8.0 * f64::EPSILON * scalar || (v == 0.0 && scalar < 1e-300);
                assert!(close, "{kernel:?}, r² = {q}: {v} vs {scalar}");
            }
        }
    }
}
