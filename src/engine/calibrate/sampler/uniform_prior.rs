//! Uniform (box) priors, as in the paper, for θ and the discrepancy
//! hyperparameters alike.

use anyhow::{bail, Result};
use rand::Rng;

#[derive(Clone, Debug)]
pub struct UniformPrior {
    pub names: Vec<String>,
    pub lower: Vec<f64>,
    pub upper: Vec<f64>,
    log_density: f64,
}

impl UniformPrior {
    pub fn new(names: Vec<String>, lower: Vec<f64>, upper: Vec<f64>) -> Result<Self> {
        assert_eq!(names.len(), lower.len());
        assert_eq!(names.len(), upper.len());
        for i in 0..names.len() {
            if !(lower[i].is_finite() && upper[i].is_finite() && lower[i] < upper[i]) {
                bail!(
                    "prior bounds for '{}' must be finite with min < max, got ({}, {})",
                    names[i],
                    lower[i],
                    upper[i]
                );
            }
        }
        let log_density = -(0..names.len()).map(|i| (upper[i] - lower[i]).ln()).sum::<f64>();
        Ok(UniformPrior { names, lower, upper, log_density })
    }

    pub fn dim(&self) -> usize {
        self.names.len()
    }

    /// Bounds are open intervals: hyperparameters such as ℓ must stay > 0.
    #[inline]
    pub fn contains(&self, x: &[f64]) -> bool {
        x.iter().zip(self.lower.iter().zip(&self.upper)).all(|(v, (lo, hi))| *v > *lo && *v < *hi)
    }

    #[inline]
    pub fn log_density(&self, x: &[f64]) -> f64 {
        if self.contains(x) {
            self.log_density
        } else {
            f64::NEG_INFINITY
        }
    }

    /// Logit map of the box onto ℝ^d. The samplers move in u, where posteriors
    /// piled against a bound (a discrepancy amplitude near 0, a length scale
    /// near its maximum) look far more Gaussian than in x.
    pub fn to_unbounded(&self, x: &[f64], u: &mut [f64]) {
        for i in 0..x.len() {
            let p = (x[i] - self.lower[i]) / (self.upper[i] - self.lower[i]);
            u[i] = (p / (1.0 - p)).ln();
        }
    }

    pub fn from_unbounded(&self, u: &[f64], x: &mut [f64]) {
        for i in 0..u.len() {
            let p = 1.0 / (1.0 + (-u[i]).exp());
            x[i] = self.lower[i] + p * (self.upper[i] - self.lower[i]);
        }
    }

    /// `from_unbounded` and `log_density_unbounded` in one pass, sharing the
    /// exponentials (this runs once per proposal in both samplers).
    #[inline]
    pub fn from_unbounded_with_log_density(&self, u: &[f64], x: &mut [f64]) -> f64 {
        let mut log_density = 0.0;
        let mut prod = 1.0;
        for i in 0..u.len() {
            let e = (-u[i].abs()).exp();
            let q = 1.0 / (1.0 + e); // σ(|u|)
            let p = if u[i] >= 0.0 { q } else { e * q };
            x[i] = self.lower[i] + p * (self.upper[i] - self.lower[i]);
            // σ(u)(1 - σ(u)) = e / (1 + e)², accumulated as a product, one log at the end.
            prod *= e * q * q;
            if prod < 1e-250 {
                log_density += prod.ln();
                prod = 1.0;
            }
        }
        log_density + prod.ln()
    }

    /// Prior log-density in u: the uniform pushed through the logit is the
    /// standard logistic, `Σ log σ(u)(1 - σ(u))`.
    #[inline]
    pub fn log_density_unbounded(&self, u: &[f64]) -> f64 {
        u.iter().map(|v| -v.abs() - 2.0 * (-v.abs()).exp().ln_1p()).sum()
    }

    /// `n` independent draws (benchmarks' evaluation points).
    pub fn draws<R: Rng + ?Sized>(&self, rng: &mut R, n: usize) -> Vec<Vec<f64>> {
        (0..n)
            .map(|_| {
                let mut x = vec![0.0; self.dim()];
                self.sample(rng, &mut x);
                x
            })
            .collect()
    }

    pub fn sample<R: Rng + ?Sized>(&self, rng: &mut R, out: &mut [f64]) {
        for i in 0..self.dim() {
            loop {
                let u: f64 = rng.random();
                let v = self.lower[i] + u * (self.upper[i] - self.lower[i]);
                if v > self.lower[i] && v < self.upper[i] {
                    out[i] = v;
                    break;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unbounded_map_round_trips_and_density_is_logistic() {
        let prior = UniformPrior::new(vec!["a".into(), "b".into()], vec![0.0, -2.0], vec![10.0, 2.0]).unwrap();
        let x = [3.7, -1.9];
        let mut u = [0.0; 2];
        prior.to_unbounded(&x, &mut u);
        let mut back = [0.0; 2];
        let fused = prior.from_unbounded_with_log_density(&u, &mut back);
        for i in 0..2 {
            assert!((back[i] - x[i]).abs() < 1e-12);
        }
        assert!((fused - prior.log_density_unbounded(&u)).abs() < 1e-12);
        // Far tails: still finite and equal to the slow form.
        let far = [-40.0, 35.0];
        assert!(
            (prior.from_unbounded_with_log_density(&far, &mut back) - prior.log_density_unbounded(&far)).abs() < 1e-9
        );
        // The logistic density integrates to one.
        let h = 0.001;
        let total: f64 = (-40000..40000).map(|k| (prior.log_density_unbounded(&[k as f64 * h])).exp() * h).sum();
        assert!((total - 1.0).abs() < 1e-6, "{total}");
    }
}
