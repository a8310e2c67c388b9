//! The screening fit: least squares of a model to the data by
//! Levenberg–Marquardt, within the prior box, from a few starting points.
//! It finds each term's best χ² in milliseconds; the evidence that judges a
//! term comes later, from the full calibration.

use super::{standardize_blocks, ScreeningBlock, Simulator};
use rayon::prelude::*;

/// A least-squares problem: the data, a model over φ, and φ's box.
pub struct LeastSquares<'a> {
    pub blocks: &'a [ScreeningBlock<'a>],
    pub model: &'a dyn Simulator,
    pub bounds: Vec<(f64, f64)>,
}

/// The best fit found: φ, its χ², and the model at the data (block by block).
#[derive(Clone, Debug)]
pub struct Fitted {
    pub phi: Vec<f64>,
    pub chi2: f64,
    pub prediction: Vec<f64>,
}

const MAX_ITERATIONS: usize = 60;

impl LeastSquares<'_> {
    pub fn points(&self) -> usize {
        self.blocks.iter().map(|b| b.x.len()).sum()
    }

    /// The model at the data, all blocks in a row; None where it cannot be computed.
    pub fn predict(&self, phi: &[f64]) -> Option<Vec<f64>> {
        let mut out = Vec::with_capacity(self.points());
        for b in self.blocks {
            let start = out.len();
            out.resize(start + b.x.len(), 0.0);
            self.model.predict(b.model_index, b.x, phi, &mut out[start..]);
        }
        out.iter().all(|v| v.is_finite()).then_some(out)
    }

    /// Standardized residuals: (y − η)/σ, or L⁻¹(y − η) where the data have a covariance.
    fn residuals(&self, prediction: &[f64]) -> Vec<f64> {
        let data = self.blocks.iter().flat_map(|b| b.y.iter());
        let mut r: Vec<f64> = data.zip(prediction).map(|(y, p)| y - p).collect();
        standardize_blocks(self.blocks, &mut r, 1.0);
        r
    }

    fn chi2(&self, phi: &[f64]) -> Option<(f64, Vec<f64>)> {
        let p = self.predict(phi)?;
        Some((self.residuals(&p).iter().map(|r| r * r).sum(), p))
    }

    /// The best of the fits from each start.
    pub fn best_of(&self, starts: &[Vec<f64>]) -> Option<Fitted> {
        // The starts are independent (two periodic terms make 256 of them);
        // the first of equal minima wins, as in order.
        let fits: Vec<Option<Fitted>> = starts.par_iter().map(|s| self.fit(s)).collect();
        fits.into_iter().flatten().min_by(|a, b| a.chi2.total_cmp(&b.chi2))
    }

    /// Levenberg–Marquardt from `start`, each step projected into the box;
    /// forward differences at 1e-7 of each parameter's range.
    pub fn fit(&self, start: &[f64]) -> Option<Fitted> {
        let mut phi: Vec<f64> = self.clamp(start.to_vec());
        let (mut chi2, mut prediction) = self.chi2(&phi)?;
        let mut lambda = 1e-3;
        for _ in 0..MAX_ITERATIONS {
            let r = self.residuals(&prediction);
            let Some(jac) = self.jacobian(&phi, &prediction) else { break };
            let (jtj, jtr) = normal_equations(&jac, &r);
            let mut improved = false;
            while lambda < 1e12 {
                let mut a = jtj.clone();
                let k = phi.len();
                for i in 0..k {
                    a[i * k + i] += lambda * jtj[i * k + i].max(1e-12);
                }
                let Some(step) = solve(a, jtr.clone()) else {
                    lambda *= 10.0;
                    continue;
                };
                let trial = self.clamp(phi.iter().zip(&step).map(|(p, s)| p + s).collect());
                match self.chi2(&trial) {
                    Some((c, p)) if c < chi2 => {
                        let converged = chi2 - c < 1e-9 * chi2.max(1.0);
                        (phi, chi2, prediction) = (trial, c, p);
                        lambda = (lambda / 5.0).max(1e-12);
                        improved = !converged;
                        break;
                    }
                    _ => lambda *= 8.0,
                }
            }
            if !improved {
                break;
            }
        }
        Some(Fitted { phi, chi2, prediction })
    }

    fn clamp(&self, mut phi: Vec<f64>) -> Vec<f64> {
        for (p, (lo, hi)) in phi.iter_mut().zip(&self.bounds) {
            *p = p.clamp(*lo, *hi);
        }
        phi
    }

    /// ∂(standardized residual)/∂φ_k, column by column (k-major).
    fn jacobian(&self, phi: &[f64], at: &[f64]) -> Option<Vec<Vec<f64>>> {
        let mut columns = Vec::with_capacity(phi.len());
        for k in 0..phi.len() {
            let (lo, hi) = self.bounds[k];
            let mut h = 1e-7 * (hi - lo).max(1e-12);
            // Step inward at the upper edge of the box.
            if phi[k] + h > hi {
                h = -h;
            }
            let mut moved = phi.to_vec();
            moved[k] += h;
            let p = self.predict(&moved)?;
            let mut column: Vec<f64> = p.iter().zip(at).map(|(p, a)| -(p - a)).collect();
            standardize_blocks(self.blocks, &mut column, h);
            columns.push(column);
        }
        Some(columns)
    }
}

/// JᵀJ (row-major k × k) and −Jᵀr, from Jacobian columns.
fn normal_equations(jac: &[Vec<f64>], r: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let k = jac.len();
    let mut jtj = vec![0.0; k * k];
    let mut jtr = vec![0.0; k];
    for i in 0..k {
        jtr[i] = -jac[i].iter().zip(r).map(|(a, b)| a * b).sum::<f64>();
        for j in 0..=i {
            let v: f64 = jac[i].iter().zip(&jac[j]).map(|(a, b)| a * b).sum();
            jtj[i * k + j] = v;
            jtj[j * k + i] = v;
        }
    }
    (jtj, jtr)
}

/// Solves the small dense system A x = b by Gaussian elimination with
/// partial pivoting; None when A is singular.
fn solve(mut a: Vec<f64>, mut b: Vec<f64>) -> Option<Vec<f64>> {
    let n = b.len();
    for col in 0..n {
        let pivot = (col..n).max_by(|&i, &j| a[i * n + col].abs().total_cmp(&a[j * n + col].abs()))?;
        if a[pivot * n + col].abs() < 1e-300 {
            return None;
        }
        for j in 0..n {
            a.swap(col * n + j, pivot * n + j);
        }
        b.swap(col, pivot);
        for row in col + 1..n {
            let f = a[row * n + col] / a[col * n + col];
            for j in col..n {
                a[row * n + j] -= f * a[col * n + j];
            }
            b[row] -= f * b[col];
        }
    }
    let mut x = vec![0.0; n];
    for row in (0..n).rev() {
        let s: f64 = (row + 1..n).map(|j| a[row * n + j] * x[j]).sum();
        x[row] = (b[row] - s) / a[row * n + row];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// y = a + b x + c x², a model the fit must recover exactly from exact data.
    struct Quadratic;
    impl Simulator for Quadratic {
        fn parameter_names(&self) -> Vec<String> {
            vec!["a".into(), "b".into(), "c".into()]
        }
        fn observable_names(&self) -> Vec<String> {
            vec!["y".into()]
        }
        fn predict(&self, _o: usize, x: &[f64], t: &[f64], out: &mut [f64]) {
            for (o, x) in out.iter_mut().zip(x) {
                *o = t[0] + t[1] * x + t[2] * x * x;
            }
        }
    }

    #[test]
    fn the_fit_recovers_a_polynomial_and_its_chi2_is_the_closed_form() {
        let x: Vec<f64> = (0..12).map(|i| i as f64 / 11.0).collect();
        let y: Vec<f64> = x.iter().map(|x| 1.0 - 2.0 * x + 0.5 * x * x).collect();
        let error = vec![0.1; x.len()];
        let blocks = [ScreeningBlock { model_index: 0, x: &x, y: &y, error: &error, covariance_factor: None }];
        let ls = LeastSquares { blocks: &blocks, model: &Quadratic, bounds: vec![(-5.0, 5.0); 3] };
        let f = ls.fit(&[0.0, 0.0, 0.0]).unwrap();
        for (got, want) in f.phi.iter().zip([1.0, -2.0, 0.5]) {
            assert!((got - want).abs() < 1e-6, "{:?}", f.phi);
        }
        assert!(f.chi2 < 1e-10, "{}", f.chi2);
        // With one point moved by 3σ the least-squares χ² is that of the
        // projection: 9 (1 − h_ii), h the hat matrix' diagonal, computed here
        // by the normal equations of the design [1, x, x²].
        let mut moved = y.clone();
        moved[5] += 0.3;
        let blocks = [ScreeningBlock { model_index: 0, x: &x, y: &moved, error: &error, covariance_factor: None }];
        let ls = LeastSquares { blocks: &blocks, model: &Quadratic, bounds: vec![(-5.0, 5.0); 3] };
        let f = ls.fit(&[0.0, 0.0, 0.0]).unwrap();
        let design: Vec<Vec<f64>> = (0..3).map(|k| x.iter().map(|x| x.powi(k)).collect()).collect();
        let (xtx, _) = normal_equations(&design, &vec![0.0; x.len()]);
        let row: Vec<f64> = (0..3).map(|k| x[5].powi(k)).collect();
        let solved = solve(xtx, row.clone()).unwrap();
        let h: f64 = row.iter().zip(&solved).map(|(a, b)| a * b).sum();
        assert!((f.chi2 - 9.0 * (1.0 - h)).abs() < 1e-6, "{} vs {}", f.chi2, 9.0 * (1.0 - h));
    }

    /// With a covariance the fit is generalized least squares: for a model
    /// linear in φ the closed form β = (XᵀC⁻¹X)⁻¹ XᵀC⁻¹y, and its χ² the
    /// (y − Xβ)ᵀ C⁻¹ (y − Xβ) at that β, computed here with the Cholesky of
    /// `engine::gp` rather than the fit's own steps.
    #[test]
    fn with_a_covariance_the_fit_is_generalized_least_squares() {
        use crate::engine::gp::CholeskyWorkspace;
        let n = 12;
        let x: Vec<f64> = (0..n).map(|i| i as f64 / 11.0).collect();
        let y: Vec<f64> = x.iter().map(|x| 1.0 - 2.0 * x + 0.5 * x * x + 0.05 * (7.0 * x).sin()).collect();
        let error = vec![0.1; n];
        // Errors 0.1 correlated by 0.6^|i − j|.
        let mut chol = CholeskyWorkspace::new(n);
        for j in 0..n {
            for i in j..n {
                chol.factor[j * n + i] = 0.01 * 0.6f64.powi((i - j) as i32);
            }
        }
        chol.factorize().unwrap();
        let blocks = [ScreeningBlock {
            model_index: 0,
            x: &x,
            y: &y,
            error: &error,
            covariance_factor: Some(chol.factor.clone()),
        }];
        let ls = LeastSquares { blocks: &blocks, model: &Quadratic, bounds: vec![(-5.0, 5.0); 3] };
        let f = ls.fit(&[0.0, 0.0, 0.0]).unwrap();
        // C⁻¹X and C⁻¹y by the Cholesky solve, then the 3 × 3 normal equations.
        let design: Vec<Vec<f64>> = (0..3).map(|k| x.iter().map(|x| x.powi(k)).collect()).collect();
        let c_inv = |v: &[f64]| {
            let mut v = v.to_vec();
            chol.solve_in_place(&mut v);
            v
        };
        let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(a, b)| a * b).sum::<f64>();
        let xtcx: Vec<f64> = (0..9).map(|k| dot(&design[k / 3], &c_inv(&design[k % 3]))).collect();
        let xtcy: Vec<f64> = (0..3).map(|k| dot(&design[k], &c_inv(&y))).collect();
        let beta = solve(xtcx, xtcy).unwrap();
        for (got, want) in f.phi.iter().zip(&beta) {
            assert!((got - want).abs() < 1e-6, "{:?} vs {beta:?}", f.phi);
        }
        let r: Vec<f64> = (0..n).map(|i| y[i] - (0..3).map(|k| beta[k] * design[k][i]).sum::<f64>()).collect();
        let chi2 = dot(&r, &c_inv(&r));
        assert!((f.chi2 - chi2).abs() < 1e-8 * chi2.max(1.0), "{} vs {chi2}", f.chi2);
        // The errors alone would give another χ²: the covariance is what was used.
        let diagonal: f64 = r.iter().map(|r| (r / 0.1).powi(2)).sum();
        assert!((diagonal - chi2).abs() > 0.1 * chi2, "{diagonal} vs {chi2}");
    }
}
