//! The paper's discrepancy kernels and the Gram matrix of one observable's
//! inputs, filled fast inside a sampler.

use crate::base::choices::Kernel;

/// The paper's two discrepancy kernels (Jaiswal et al. 2025, eqs. for Kernel I/II).
///
/// Kernel I:  `s² + c̄² (x x')^r exp(-|x-x'|²/2ℓ²)`;
/// Kernel II: the same without `s²`.
/// The `(x x')^r` factor lets the discrepancy grow (r > 0) away from x = 0,
/// where for the ball drop model and truth coincide by construction.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum DiscrepancyKernel {
    #[serde(rename = "I")]
    KernelI,
    #[serde(rename = "II")]
    KernelII,
}

impl DiscrepancyKernel {
    /// Hyperparameter names in the order they appear in parameter vectors.
    pub fn hyper_names(self) -> &'static [&'static str] {
        match self {
            DiscrepancyKernel::KernelI => &["cbar", "ell", "r", "s"],
            DiscrepancyKernel::KernelII => &["cbar", "ell", "r"],
        }
    }

    pub fn n_hyper(self) -> usize {
        self.hyper_names().len()
    }

    /// The kernel of a user's choice (`None`: the fit without MD).
    pub fn of(choice: Kernel) -> Option<DiscrepancyKernel> {
        match choice {
            Kernel::None => None,
            Kernel::I => Some(DiscrepancyKernel::KernelI),
            Kernel::II => Some(DiscrepancyKernel::KernelII),
        }
    }

    /// The user's choice a kernel (or none) is.
    pub fn choice(kernel: Option<DiscrepancyKernel>) -> Kernel {
        match kernel {
            None => Kernel::None,
            Some(DiscrepancyKernel::KernelI) => Kernel::I,
            Some(DiscrepancyKernel::KernelII) => Kernel::II,
        }
    }

    pub fn label(kernel: Option<DiscrepancyKernel>) -> &'static str {
        match kernel {
            None => "none",
            Some(DiscrepancyKernel::KernelI) => "I",
            Some(DiscrepancyKernel::KernelII) => "II",
        }
    }
}

/// `x^r` with the convention `0^r = 0` for r > 0 and `0^0 = 1`.
#[inline]
pub fn pow_r(x: f64, r: f64) -> f64 {
    if x == 0.0 {
        if r == 0.0 {
            1.0
        } else {
            0.0
        }
    } else {
        x.powf(r)
    }
}

/// Kernel evaluation between two sets of inputs, written into `out`
/// (column-major, `xa.len()` rows by `xb.len()` columns).
pub fn discrepancy_cross_cov(kernel: DiscrepancyKernel, hyper: &[f64], xa: &[f64], xb: &[f64], out: &mut [f64]) {
    let (cbar, ell, r) = (hyper[0], hyper[1], hyper[2]);
    let s2 = match kernel {
        DiscrepancyKernel::KernelI => hyper[3] * hyper[3],
        DiscrepancyKernel::KernelII => 0.0,
    };
    let c2 = cbar * cbar;
    let inv_two_ell2 = 0.5 / (ell * ell);
    let n = xa.len();
    for (j, &xj) in xb.iter().enumerate() {
        let pj = pow_r(xj, r);
        for (i, &xi) in xa.iter().enumerate() {
            let d = xi - xj;
            out[i + j * n] = s2 + c2 * pow_r(xi, r) * pj * (-d * d * inv_two_ell2).exp();
        }
    }
}

/// Precomputed inputs for filling `K(x, x)` fast inside a sampler: squared
/// distances are fixed, only the hyperparameters change.
#[derive(Clone, Debug)]
pub struct DiscrepancyGram {
    pub x: Vec<f64>,
    ln_x: Vec<f64>,
    /// Distinct squared distances (equally spaced inputs have only n of them).
    unique_sq_dist: Vec<f64>,
    /// For the packed lower triangle (by column), the index into `unique_sq_dist`.
    pair_index: Vec<u32>,
    /// `Some(h²)` when `unique_sq_dist[k] = (k h)²` (an equally spaced grid):
    /// then `exp(-k²h²/2ℓ²) = q^(k²)` follows from one exp by recurrence.
    equal_lag_sq: Option<f64>,
}

impl DiscrepancyGram {
    pub fn new(x: &[f64]) -> Self {
        let n = x.len();
        let mut unique_sq_dist: Vec<f64> = Vec::new();
        let mut pair_index = Vec::with_capacity(n * (n + 1) / 2);
        for j in 0..n {
            for i in j..n {
                let d = x[i] - x[j];
                let d2 = d * d;
                // Lags of an equally spaced grid agree to rounding; merging them
                // changes K by ~1e-13 relative and saves most of the exp calls.
                let tol = 1e-13 * d2.max(1e-300);
                let k = match unique_sq_dist.iter().position(|u| (u - d2).abs() <= tol) {
                    Some(k) => k,
                    None => {
                        unique_sq_dist.push(d2);
                        unique_sq_dist.len() - 1
                    }
                };
                pair_index.push(k as u32);
            }
        }
        let equal_lag_sq = unique_sq_dist.get(1).copied().filter(|&h2| {
            h2 > 0.0
                && unique_sq_dist
                    .iter()
                    .enumerate()
                    .all(|(k, &d2)| (d2 - (k * k) as f64 * h2).abs() <= 1e-12 * d2.max(h2))
        });
        DiscrepancyGram {
            x: x.to_vec(),
            ln_x: x.iter().map(|v| v.ln()).collect(),
            unique_sq_dist,
            pair_index,
            equal_lag_sq,
        }
    }

    pub fn len(&self) -> usize {
        self.x.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Writes the lower triangle of `K(x,x)` (column-major `n*n`).
    /// `xr` is scratch of length n for `x_i^r`; `corr` of length at least `n_unique()`.
    #[inline]
    pub fn fill_lower(
        &self,
        kernel: DiscrepancyKernel,
        hyper: &[f64],
        out: &mut [f64],
        xr: &mut [f64],
        corr: &mut [f64],
    ) {
        let n = self.x.len();
        let (cbar, ell, r) = (hyper[0], hyper[1], hyper[2]);
        let s2 = match kernel {
            DiscrepancyKernel::KernelI => hyper[3] * hyper[3],
            DiscrepancyKernel::KernelII => 0.0,
        };
        let c2 = cbar * cbar;
        for i in 0..n {
            // x^r = exp(r ln x): one exp per point instead of one powf per pair.
            xr[i] = if self.x[i] == 0.0 { pow_r(0.0, r) } else { (r * self.ln_x[i]).exp() };
        }
        let neg_inv_two_ell2 = -0.5 / (ell * ell);
        // Callers share one scratch across blocks, sized for the block with
        // the most distinct lags; this block uses its own count of them.
        let corr = &mut corr[..self.unique_sq_dist.len()];
        match self.equal_lag_sq {
            // q^(k²) = q^((k-1)²) · q^(2k-1): one exp instead of one per lag,
            // with a relative error of a few ulp over a grid of tens of points.
            // Past ~1e-280 the products would turn subnormal (slow, inexact);
            // exp is exact there, so the recurrence stops.
            Some(h2) => {
                let q = (h2 * neg_inv_two_ell2).exp();
                let q2 = q * q;
                let (mut value, mut step) = (1.0, q);
                for (k, c) in corr.iter_mut().enumerate() {
                    if value < 1e-280 {
                        *c = (self.unique_sq_dist[k] * neg_inv_two_ell2).exp();
                        continue;
                    }
                    *c = value;
                    value *= step;
                    step *= q2;
                }
            }
            None => {
                for (c, d2) in corr.iter_mut().zip(&self.unique_sq_dist) {
                    *c = (d2 * neg_inv_two_ell2).exp();
                }
            }
        }
        let mut k = 0;
        for j in 0..n {
            let cj = c2 * xr[j];
            for i in j..n {
                out[i + j * n] = s2 + cj * xr[i] * corr[self.pair_index[k] as usize];
                k += 1;
            }
        }
    }

    pub fn n_unique(&self) -> usize {
        self.unique_sq_dist.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gram_fill_matches_cross_cov() {
        let x = [0.1, 0.35, 0.8, 1.0];
        let h = [1.3, 0.4, 1.7, 0.2];
        let g = DiscrepancyGram::new(&x);
        let mut lower = vec![0.0; 16];
        let mut xr = vec![0.0; 4];
        let mut corr = vec![0.0; g.n_unique()];
        g.fill_lower(DiscrepancyKernel::KernelI, &h, &mut lower, &mut xr, &mut corr);
        let mut full = vec![0.0; 16];
        discrepancy_cross_cov(DiscrepancyKernel::KernelI, &h, &x, &x, &mut full);
        for j in 0..4 {
            for i in j..4 {
                assert!((lower[i + 4 * j] - full[i + 4 * j]).abs() < 1e-14);
            }
        }
        // Kernel I at x = x' = 1: s² + c̄².
        assert!((full[15] - (0.04 + 1.69)).abs() < 1e-12);
    }

    #[test]
    fn equally_spaced_gram_recurrence_matches_direct_exp() {
        // The ball drop's times (0..1 s in 9 steps) and the heavy-ion pT bin
        // midpoints, at length scales from tiny (underflowing lags) to long.
        let grids: [Vec<f64>; 2] =
            [(0..10).map(|i| i as f64 / 9.0).collect(), (0..10).map(|i| 0.1 + 0.2 * i as f64).collect()];
        for x in &grids {
            let n = x.len();
            let g = DiscrepancyGram::new(x);
            assert!(g.equal_lag_sq.is_some(), "grid {x:?} should be recognised as equally spaced");
            for ell in [0.003, 0.05, 0.4, 2.0, 9.5] {
                let h = [1.3, ell, 1.7, 0.2];
                let (mut lower, mut full) = (vec![0.0; n * n], vec![0.0; n * n]);
                let (mut xr, mut corr) = (vec![0.0; n], vec![0.0; g.n_unique()]);
                g.fill_lower(DiscrepancyKernel::KernelII, &h, &mut lower, &mut xr, &mut corr);
                discrepancy_cross_cov(DiscrepancyKernel::KernelII, &h, x, x, &mut full);
                for j in 0..n {
                    for i in j..n {
                        let (a, b) = (lower[i + n * j], full[i + n * j]);
                        // exp(u) inherits u's rounding as |u|·ε relative error, whichever
                        // way it is computed; allow that plus a few ulp per recurrence step.
                        let cond = 1.0 + b.abs().max(1e-300).ln().abs();
                        assert!((a - b).abs() <= 1e-14 * cond * b.abs() + 1e-300, "ell {ell}, ({i},{j}): {a} vs {b}");
                    }
                }
            }
        }
        assert!(DiscrepancyGram::new(&[0.1, 0.35, 0.8, 1.0]).equal_lag_sq.is_none());
    }

    /// The likelihood shares one `corr` scratch across blocks, sized for the
    /// block with the most distinct lags. An equally spaced block with a
    /// repeated point has fewer lags than points, and filling it with the
    /// longer scratch indexed past its lags (a panic, found when repeated
    /// measurements were added at one x of one of two observables).
    #[test]
    fn a_block_fills_from_scratch_longer_than_its_lags() {
        let x = [0.0, 0.5, 1.0, 1.5, 1.5];
        let g = DiscrepancyGram::new(&x);
        assert!(g.equal_lag_sq.is_some() && g.n_unique() == 4);
        let h = [1.3, 0.4, 1.7, 0.2];
        let (mut lower, mut full) = (vec![0.0; 25], vec![0.0; 25]);
        let (mut xr, mut corr) = (vec![0.0; 5], vec![0.0; 9]);
        g.fill_lower(DiscrepancyKernel::KernelI, &h, &mut lower, &mut xr, &mut corr);
        discrepancy_cross_cov(DiscrepancyKernel::KernelI, &h, &x, &x, &mut full);
        for j in 0..5 {
            for i in j..5 {
                assert!((lower[i + 5 * j] - full[i + 5 * j]).abs() < 1e-14, "({i},{j})");
            }
        }
    }
}
